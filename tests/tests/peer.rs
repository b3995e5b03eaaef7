//! An independent peer on the real binary: Modbus RTU and 3964R framing written here from the
//! manual (003 6.3, 6.4.3, 6.4.6), without proto-core, driving `gateway run` lines over socat
//! pty links. A simulator built on the gateway's own engines cannot catch a misread rule; this
//! peer frames, checks and answers with its own code.
//!
//! - a reply with trailing bytes fails with 0E 53h and its values are not taken; the same device
//!   answering cleanly is read again (003 6.4.3, 7.2 0E 53h);
//! - a slave request with trailing bytes is not answered, the clean request is (003 6.4.6);
//! - a 3964R telegram with a wrong BCC is answered with NAK, its repetition with DLE, and only the
//!   good one reaches the mailbox (003 6.3.1 "Block check character");
//! - a 3964R telegram that stops halfway is answered with NAK once the character delay time has
//!   passed (003 6.3.1 "Passive operation", 7.2 08 06h);
//! - a Modbus ASCII reply in lower-case hex fails with 0E 58h and its values are not taken
//!   (7.2 0E 58h: only 0...9, A...F);
//! - a 3964R telegram of the gateway answered with NAK is repeated from the connection setup
//!   (003 6.3.1 "Timeout times");
//! - the initialization conflict in both priorities: the low-priority station answers the other's
//!   STX with DLE and receives first (003 6.3.1 "Initialization conflict").

use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use gateway_tests::{temp_dir, Gateway, SocatLink};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::prelude::Slave;
use tokio_serial::{SerialPortBuilderExt, SerialStream};

// --- Framing of our own ---

/// CRC-16 as Modbus RTU uses it (polynomial A001h reflected, start FFFFh), low byte sent first.
fn crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &byte in data {
        crc ^= u16::from(byte);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    crc
}

/// `body` with its CRC appended.
fn with_crc(body: &[u8]) -> Vec<u8> {
    let crc = crc16(body).to_le_bytes();
    let mut frame = body.to_vec();
    frame.extend_from_slice(&crc);
    frame
}

/// Whether `frame` ends with the CRC of the rest.
fn crc_ok(frame: &[u8]) -> bool {
    frame.len() >= 4 && {
        let (body, crc) = frame.split_at(frame.len() - 2);
        crc16(body).to_le_bytes() == crc
    }
}

const STX: u8 = 0x02;
const ETX: u8 = 0x03;
const DLE: u8 = 0x10;
const NAK: u8 = 0x15;

/// A 3964R block: data with DLE doubled, DLE ETX, and the XOR of all of it as BCC (003 6.3.1).
fn block_3964r(data: &[u8]) -> Vec<u8> {
    let mut block = Vec::new();
    for &b in data {
        block.push(b);
        if b == DLE {
            block.push(DLE);
        }
    }
    block.extend_from_slice(&[DLE, ETX]);
    let bcc = block.iter().fold(0u8, |acc, b| acc ^ b);
    block.push(bcc);
    block
}

// --- The peer's line ---

/// Opens the peer's end of a link (8E1 as the gateway's line; a pty ignores it).
fn open(port: &Path, baud: u32) -> SerialStream {
    tokio_serial::new(port.to_str().expect("utf-8 path"), baud)
        .parity(tokio_serial::Parity::Even)
        .open_native_async()
        .expect("open the peer's end")
}

/// Waits up to `first` for a byte, then collects until `silence` passes without one: one frame as
/// the line delimits it. Empty if nothing came.
async fn read_frame(port: &mut SerialStream, first: Duration, silence: Duration) -> Vec<u8> {
    let mut frame = Vec::new();
    let mut buf = [0u8; 512];
    let mut wait = first;
    while let Ok(Ok(n)) = tokio::time::timeout(wait, port.read(&mut buf)).await {
        if n == 0 {
            break;
        }
        frame.extend_from_slice(&buf[..n]);
        wait = silence;
    }
    frame
}

// --- The gateway and what it shows ---

fn start_gateway(dir: &Path, config: &str) -> Gateway {
    let file = dir.join("gateway.toml");
    std::fs::write(&file, config).expect("write config");
    let gw = Gateway::run(&file);
    assert!(gw.http.is_some(), "no HTTP listener announced");
    gw
}

fn head() -> String {
    "[gateway]\nname = \"peer\"\n\n[modbus_tcp]\nlisten = \"127.0.0.1:0\"\n".to_owned()
}

/// `gateway_events_total` of `event` (four hex digits) on `line`, from `/metrics`.
async fn event_count(http: SocketAddr, line: &str, event: &str) -> f64 {
    let mut stream = TcpStream::connect(http).await.expect("connect to /metrics");
    stream
        .write_all(
            format!("GET /metrics HTTP/1.1\r\nHost: {http}\r\nConnection: close\r\n\r\n")
                .as_bytes(),
        )
        .await
        .expect("request /metrics");
    let mut text = String::new();
    stream
        .read_to_string(&mut text)
        .await
        .expect("read /metrics");
    let labels = [format!("line=\"{line}\""), format!("event=\"{event}\"")];
    text.lines()
        .filter(|l| l.starts_with("gateway_events_total{"))
        .filter(|l| labels.iter().all(|label| l.contains(label.as_str())))
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum()
}

// --- Modbus RTU: the gateway as master ---

/// The Altivar's W3102..W3105 as this peer serves them.
const WORDS: [u16; 4] = [40, 600, 500, 0];

/// Serves FC 03 as slave 2 until the test ends; with `trailing` set, every answer carries two
/// extra bytes in the same write (inside the 3.5 character silence that would end it).
async fn rtu_slave(mut port: SerialStream, trailing: Arc<AtomicBool>) {
    loop {
        let request = read_frame(
            &mut port,
            Duration::from_secs(3600),
            Duration::from_millis(5),
        )
        .await;
        if request.len() != 8 || !crc_ok(&request) || request[0] != 2 || request[1] != 3 {
            continue;
        }
        let start = u16::from_be_bytes([request[2], request[3]]);
        let count = u16::from_be_bytes([request[4], request[5]]);
        let mut body = vec![2, 3, u8::try_from(count * 2).expect("count")];
        for i in 0..count {
            let value = if start == 3102 && i < 4 {
                WORDS[usize::from(i)]
            } else {
                0
            };
            body.extend_from_slice(&value.to_be_bytes());
        }
        let mut answer = with_crc(&body);
        if trailing.load(Ordering::SeqCst) {
            answer.extend_from_slice(&[0x00, 0x00]);
        }
        tokio::time::sleep(Duration::from_millis(3)).await;
        if port.write_all(&answer).await.is_err() {
            return;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reply_with_trailing_bytes_fails_with_0e53_and_its_values_are_not_taken() {
    let dir = temp_dir("peer-trailing-reply");
    let link = SocatLink::new(&dir, "drive");
    let trailing = Arc::new(AtomicBool::new(true));
    let config = head()
        + &format!(
            r#"
[lines.drive]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "300ms"

[lines.drive.devices.atv71]
profile = "altivar71"
address = 2
unit_id = 2
offline_backoff_min = "200ms"
offline_backoff_max = "1s"

[[lines.drive.devices.atv71.poll]]
name = "settings"
period = "100ms"
ranges = [{{ table = "holding", start = 3102, count = 4 }}]
"#,
            port = link.a.display()
        );
    let peer = tokio::spawn(rtu_slave(open(&link.b, 19200), Arc::clone(&trailing)));
    let gw = start_gateway(&dir, &config);
    let http = gw.http.expect("http");
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");

    // Every reply is two bytes longer than its byte count: 0E 53h, and no values.
    let deadline = Instant::now() + Duration::from_secs(20);
    while event_count(http, "drive", "0E53").await < 3.0 {
        assert!(Instant::now() < deadline, "0E 53h not counted within 20 s");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let answer = ctx
        .read_holding_registers(3102, 4)
        .await
        .expect("transport");
    assert!(
        answer.is_err(),
        "values of overlong replies were taken: {answer:?}"
    );

    // The same device answering cleanly is read.
    trailing.store(false, Ordering::SeqCst);
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let answer = ctx
            .read_holding_registers(3102, 4)
            .await
            .expect("transport");
        if answer.as_deref() == Ok(&WORDS[..]) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "clean replies not read within 20 s: {answer:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    peer.abort();
}

// --- Modbus RTU: the gateway as slave ---

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slave_request_with_trailing_bytes_is_not_answered() {
    let dir = temp_dir("peer-trailing-request");
    let link = SocatLink::new(&dir, "hmi");
    let config = head()
        + &format!(
            r#"
[lines.hmi]
port = "{port}"
protocol = "modbus-slave-rtu"
baud = 9600
parity = "even"
address = 222
unit_id = 50
"#,
            port = link.a.display()
        );
    let _gw = start_gateway(&dir, &config);
    let mut port = open(&link.b, 9600);
    // FC 03, holding register 0, 2 registers.
    let request = with_crc(&[222, 0x03, 0x00, 0x00, 0x00, 0x02]);
    let expected = with_crc(&[222, 0x03, 0x04, 0, 0, 0, 0]);

    // The line is up once a clean request is answered.
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        port.write_all(&request).await.expect("write");
        let answer = read_frame(
            &mut port,
            Duration::from_millis(500),
            Duration::from_millis(10),
        )
        .await;
        if answer == expected {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "no answer to a clean request within 20 s: {answer:02X?}"
        );
    }
    // Trailing bytes in the same write: one frame longer than its request, not answered.
    for trailing in [&[0x00][..], &[0x12, 0x34], &request] {
        let mut frame = request.clone();
        frame.extend_from_slice(trailing);
        port.write_all(&frame).await.expect("write");
        let answer = read_frame(
            &mut port,
            Duration::from_millis(300),
            Duration::from_millis(10),
        )
        .await;
        assert!(
            answer.is_empty(),
            "answered a request with {} trailing bytes: {answer:02X?}",
            trailing.len()
        );
    }
    // The clean request still is.
    port.write_all(&request).await.expect("write");
    let answer = read_frame(
        &mut port,
        Duration::from_millis(500),
        Duration::from_millis(10),
    )
    .await;
    assert_eq!(answer, expected);
}

// --- 3964R ---

/// Reads one byte within `limit`.
async fn read_byte(port: &mut SerialStream, limit: Duration) -> Option<u8> {
    let mut byte = [0u8; 1];
    match tokio::time::timeout(limit, port.read(&mut byte)).await {
        Ok(Ok(1)) => Some(byte[0]),
        _ => None,
    }
}

/// One send attempt as the low-priority partner: STX, the gateway's DLE, the block, and what the
/// gateway answers to the block (DLE accepted, NAK rejected).
async fn send_3964r(port: &mut SerialStream, block: &[u8]) -> Option<u8> {
    port.write_all(&[STX]).await.ok()?;
    let setup = read_byte(port, Duration::from_secs(2)).await?;
    assert_eq!(setup, DLE, "the gateway answers STX with DLE");
    port.write_all(block).await.ok()?;
    read_byte(port, Duration::from_secs(2)).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_3964r_block_with_a_wrong_bcc_is_refused_and_its_repetition_taken() {
    let dir = temp_dir("peer-3964r-bcc");
    let link = SocatLink::new(&dir, "r3964");
    let config = head()
        + &format!(
            r#"
[lines.r3964]
port = "{port}"
protocol = "3964r"
baud = 9600
parity = "even"
block_check = true
priority = "high"
unit_id = 100
"#,
            port = link.a.display()
        );
    let gw = start_gateway(&dir, &config);
    let mut port = open(&link.b, 9600);
    let data = b"PEER\x10TELEGRAM";
    let good = block_3964r(data);
    let mut bad = good.clone();
    *bad.last_mut().expect("bcc") ^= 0x5A;

    // The gateway may still be opening its port: repeat the bad block until it is answered.
    let deadline = Instant::now() + Duration::from_secs(20);
    let refused = loop {
        if let Some(answer) = send_3964r(&mut port, &bad).await {
            break answer;
        }
        assert!(Instant::now() < deadline, "no answer to STX within 20 s");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert_eq!(refused, NAK, "a wrong BCC is answered with NAK (003 6.3.1)");
    // The repetition with the right BCC is acknowledged.
    tokio::time::sleep(Duration::from_millis(50)).await;
    let accepted = send_3964r(&mut port, &good).await;
    assert_eq!(accepted, Some(DLE));

    // Only the good telegram is in the mailbox: SEQ 1, the data undoubled.
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(100))
        .await
        .expect("connect");
    let deadline = Instant::now() + Duration::from_secs(10);
    let regs = loop {
        let regs = ctx
            .read_holding_registers(0, 4 + 8)
            .await
            .expect("transport")
            .expect("the receive block");
        if regs[1] != 0 {
            break regs;
        }
        assert!(Instant::now() < deadline, "no telegram in the mailbox");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert_eq!(regs[1], 1, "the refused block is not a telegram");
    assert_eq!(usize::from(regs[2]), data.len());
    let bytes: Vec<u8> = regs[4..]
        .iter()
        .flat_map(|w| w.to_be_bytes())
        .take(data.len())
        .collect();
    assert_eq!(bytes, data);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_3964r_telegram_that_stops_halfway_is_answered_with_nak_after_the_zvz() {
    let dir = temp_dir("peer-3964r-zvz");
    let link = SocatLink::new(&dir, "r3964");
    let config = head()
        + &format!(
            r#"
[lines.r3964]
port = "{port}"
protocol = "3964r"
baud = 9600
parity = "even"
block_check = true
priority = "high"
character_delay = "220ms"
unit_id = 100
"#,
            port = link.a.display()
        );
    let gw = start_gateway(&dir, &config);
    let http = gw.http.expect("http");
    let mut port = open(&link.b, 9600);
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        port.write_all(&[STX]).await.expect("write");
        if read_byte(&mut port, Duration::from_millis(500)).await == Some(DLE) {
            break;
        }
        assert!(Instant::now() < deadline, "no DLE to STX within 20 s");
    }
    // Half a telegram, then nothing: NAK after the ZVZ (220 ms), not before.
    port.write_all(b"HALF").await.expect("write");
    let sent = Instant::now();
    let answer = read_byte(&mut port, Duration::from_secs(3)).await;
    let after = sent.elapsed();
    assert_eq!(answer, Some(NAK));
    assert!(
        after >= Duration::from_millis(200),
        "NAK after {after:?}, before the character delay time"
    );
    let deadline = Instant::now() + Duration::from_secs(5);
    while event_count(http, "r3964", "0806").await < 1.0 {
        assert!(Instant::now() < deadline, "08 06h not counted");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // A whole telegram afterwards is taken.
    assert_eq!(
        send_3964r(&mut port, &block_3964r(b"WHOLE")).await,
        Some(DLE)
    );
}

// --- Modbus ASCII: the gateway as master ---

/// The LRC of Modbus ASCII: the two's complement of the byte sum.
fn lrc(data: &[u8]) -> u8 {
    data.iter()
        .fold(0u8, |acc, b| acc.wrapping_add(*b))
        .wrapping_neg()
}

/// Bytes from hex text (either case: the peer reads what the gateway sends, upper case).
fn from_hex(text: &[u8]) -> Option<Vec<u8>> {
    let digit = |c: u8| {
        char::from(c)
            .to_digit(16)
            .and_then(|d| u8::try_from(d).ok())
    };
    text.chunks(2)
        .map(|pair| match pair {
            [hi, lo] => Some(digit(*hi)? << 4 | digit(*lo)?),
            _ => None,
        })
        .collect()
}

/// Serves FC 03 as slave 2 in Modbus ASCII; with `lower` set, the reply's hex is lower case.
async fn ascii_slave(mut port: SerialStream, lower: Arc<AtomicBool>) {
    let mut line = Vec::new();
    let mut buf = [0u8; 256];
    loop {
        let Ok(n) = port.read(&mut buf).await else {
            return;
        };
        if n == 0 {
            return;
        }
        line.extend_from_slice(&buf[..n]);
        let Some(end) = line.windows(2).position(|w| w == b"\r\n") else {
            continue;
        };
        let frame: Vec<u8> = line.drain(..end + 2).collect();
        let Some(start) = frame.iter().position(|&b| b == b':') else {
            continue;
        };
        let Some(bytes) = from_hex(&frame[start + 1..frame.len() - 2]) else {
            continue;
        };
        let Some((&check, body)) = bytes.split_last() else {
            continue;
        };
        if lrc(body) != check || body.len() != 6 || body[0] != 2 || body[1] != 3 {
            continue;
        }
        let start_reg = u16::from_be_bytes([body[2], body[3]]);
        let count = u16::from_be_bytes([body[4], body[5]]);
        let mut reply = vec![2, 3, u8::try_from(count * 2).expect("count")];
        for i in 0..count {
            let value = if start_reg == 3102 && i < 4 {
                WORDS[usize::from(i)]
            } else {
                0
            };
            reply.extend_from_slice(&value.to_be_bytes());
        }
        reply.push(lrc(&reply));
        let hex: String = reply.iter().map(|b| format!("{b:02X}")).collect();
        let hex = if lower.load(Ordering::SeqCst) {
            hex.to_ascii_lowercase()
        } else {
            hex
        };
        let text = format!(":{hex}\r\n");
        if port.write_all(text.as_bytes()).await.is_err() {
            return;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_modbus_ascii_reply_in_lower_case_hex_fails_with_0e58() {
    let dir = temp_dir("peer-ascii-lower");
    let link = SocatLink::new(&dir, "meter");
    let lower = Arc::new(AtomicBool::new(true));
    let config = head()
        + &format!(
            r#"
[lines.meter]
port = "{port}"
protocol = "modbus-master-ascii"
baud = 19200
parity = "even"
reply_timeout = "300ms"

[lines.meter.devices.atv71]
profile = "altivar71"
address = 2
unit_id = 2
offline_backoff_min = "200ms"
offline_backoff_max = "1s"

[[lines.meter.devices.atv71.poll]]
name = "settings"
period = "100ms"
ranges = [{{ table = "holding", start = 3102, count = 4 }}]
"#,
            port = link.a.display()
        );
    let peer = tokio::spawn(ascii_slave(open(&link.b, 19200), Arc::clone(&lower)));
    let gw = start_gateway(&dir, &config);
    let http = gw.http.expect("http");
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");
    let deadline = Instant::now() + Duration::from_secs(20);
    while event_count(http, "meter", "0E58").await < 3.0 {
        assert!(Instant::now() < deadline, "0E 58h not counted within 20 s");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let answer = ctx
        .read_holding_registers(3102, 4)
        .await
        .expect("transport");
    assert!(answer.is_err(), "lower-case values were taken: {answer:?}");
    // Upper case from the same device is read.
    lower.store(false, Ordering::SeqCst);
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let answer = ctx
            .read_holding_registers(3102, 4)
            .await
            .expect("transport");
        if answer.as_deref() == Ok(&WORDS[..]) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "upper-case replies not read within 20 s: {answer:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    peer.abort();
}

// --- 3964R: the gateway sends ---

/// The 3964R line with the gateway at `priority`.
fn r3964_config(port: &Path, priority: &str) -> String {
    head()
        + &format!(
            r#"
[lines.r3964]
port = "{port}"
protocol = "3964r"
baud = 9600
parity = "even"
block_check = true
priority = "{priority}"
unit_id = 100
"#,
            port = port.display()
        )
}

/// Starts a send of `data` through the mailbox's send block as request `req` (docs/mailbox.md:
/// REQ at 1008, TX_LEN, TX_DATA high byte first).
async fn mailbox_send(ctx: &mut Context, req: u16, data: &[u8]) {
    let mut regs = vec![req, u16::try_from(data.len()).expect("len")];
    regs.extend(
        data.chunks(2)
            .map(|c| u16::from_be_bytes([c[0], c.get(1).copied().unwrap_or(0)])),
    );
    ctx.write_multiple_registers(1008, &regs)
        .await
        .expect("transport")
        .expect("the send block takes the request");
}

/// DONE, ERROR, TX_STATUS of request `req` once it has finished.
async fn mailbox_result(ctx: &mut Context, req: u16) -> (u16, u16, u16) {
    let deadline = Instant::now() + Duration::from_secs(15);
    loop {
        let r = ctx
            .read_holding_registers(1000, 5)
            .await
            .expect("transport")
            .expect("the send block");
        if r[4] == req && r[3] == 0 && (r[0] == 1 || r[1] == 1) {
            return (r[0], r[1], r[2]);
        }
        assert!(
            Instant::now() < deadline,
            "request {req} did not finish: {r:?}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Reads a 3964R block up to DLE ETX BCC and returns its data (DLE undoubled) if the BCC is right.
async fn read_block(port: &mut SerialStream) -> Option<Vec<u8>> {
    let mut raw = Vec::new();
    loop {
        let byte = read_byte(port, Duration::from_millis(500)).await?;
        raw.push(byte);
        let n = raw.len();
        // DLE ETX BCC with the DLE not itself the second half of a doubled DLE.
        if n >= 3 && raw[n - 3] == DLE && raw[n - 2] == ETX {
            let before = raw[..n - 3].iter().rev().take_while(|&&b| b == DLE).count();
            if before % 2 == 0 {
                break;
            }
        }
    }
    let (bcc, block) = raw.split_last()?;
    if block.iter().fold(0u8, |acc, b| acc ^ b) != *bcc {
        return None;
    }
    let mut data = Vec::new();
    let mut body = block[..block.len() - 2].iter();
    while let Some(&b) = body.next() {
        data.push(b);
        if b == DLE {
            body.next();
        }
    }
    Some(data)
}

/// Waits for the gateway's STX (the port may still be opening).
async fn await_stx(port: &mut SerialStream) {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        if read_byte(port, Duration::from_millis(500)).await == Some(STX) {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "no STX from the gateway within 20 s"
        );
    }
}

/// A gateway on a 3964R line at `priority`, a Modbus TCP client of its mailbox and the peer's end.
async fn r3964_line(test: &str, priority: &str) -> (Gateway, Context, SerialStream, SocatLink) {
    let dir = temp_dir(test);
    let link = SocatLink::new(&dir, "r3964");
    let gw = start_gateway(&dir, &r3964_config(&link.a, priority));
    let port = open(&link.b, 9600);
    let ctx = tcp::connect_slave(gw.modbus_tcp, Slave(100))
        .await
        .expect("connect");
    (gw, ctx, port, link)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_3964r_telegram_answered_with_nak_is_repeated_from_the_setup() {
    let (_gw, mut ctx, mut port, _link) = r3964_line("peer-3964r-nak", "high").await;
    let data = b"OUT\x10GOING";
    mailbox_send(&mut ctx, 1, data).await;
    await_stx(&mut port).await;
    port.write_all(&[DLE]).await.expect("write");
    assert_eq!(read_block(&mut port).await.as_deref(), Some(&data[..]));
    // 003 6.3.1: "when a character other than DLE is received the attempt to establish the
    // connection and the telegram are repeated".
    port.write_all(&[NAK]).await.expect("write");
    assert_eq!(
        read_byte(&mut port, Duration::from_secs(3)).await,
        Some(STX)
    );
    port.write_all(&[DLE]).await.expect("write");
    assert_eq!(read_block(&mut port).await.as_deref(), Some(&data[..]));
    port.write_all(&[DLE]).await.expect("write");
    assert_eq!(mailbox_result(&mut ctx, 1).await, (1, 0, 0));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn initialization_conflict_the_gateway_at_low_priority_yields() {
    let (_gw, mut ctx, mut port, _link) = r3964_line("peer-3964r-conflict-low", "low").await;
    let ours = b"GATEWAY";
    mailbox_send(&mut ctx, 1, ours).await;
    await_stx(&mut port).await;
    // Both sent STX: the peer has high priority and insists.
    port.write_all(&[STX]).await.expect("write");
    assert_eq!(
        read_byte(&mut port, Duration::from_secs(3)).await,
        Some(DLE),
        "the low-priority gateway answers our STX with DLE"
    );
    let theirs = b"PEER FIRST";
    port.write_all(&block_3964r(theirs)).await.expect("write");
    assert_eq!(
        read_byte(&mut port, Duration::from_secs(3)).await,
        Some(DLE)
    );
    // Then the gateway's own telegram.
    assert_eq!(
        read_byte(&mut port, Duration::from_secs(5)).await,
        Some(STX)
    );
    port.write_all(&[DLE]).await.expect("write");
    assert_eq!(read_block(&mut port).await.as_deref(), Some(&ours[..]));
    port.write_all(&[DLE]).await.expect("write");
    assert_eq!(mailbox_result(&mut ctx, 1).await, (1, 0, 0));
    let regs = ctx
        .read_holding_registers(0, 4 + 5)
        .await
        .expect("transport")
        .expect("the receive block");
    assert_eq!((regs[1], usize::from(regs[2])), (1, theirs.len()));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn initialization_conflict_the_gateway_at_high_priority_insists() {
    let (_gw, mut ctx, mut port, _link) = r3964_line("peer-3964r-conflict-high", "high").await;
    let ours = b"GATEWAY";
    mailbox_send(&mut ctx, 1, ours).await;
    await_stx(&mut port).await;
    // Both sent STX: the peer has low priority, so its STX is not answered ...
    port.write_all(&[STX]).await.expect("write");
    assert_eq!(
        read_byte(&mut port, Duration::from_millis(300)).await,
        None,
        "the high-priority gateway does not answer the crossing STX"
    );
    // ... and it yields: DLE, and the gateway's telegram comes.
    port.write_all(&[DLE]).await.expect("write");
    assert_eq!(read_block(&mut port).await.as_deref(), Some(&ours[..]));
    port.write_all(&[DLE]).await.expect("write");
    assert_eq!(mailbox_result(&mut ctx, 1).await, (1, 0, 0));
    // Its own telegram afterwards.
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert_eq!(
        send_3964r(&mut port, &block_3964r(b"PEER")).await,
        Some(DLE)
    );
}

// --- ASCII: full duplex ---

/// An ASCII line that ends a received telegram by the character delay time (003 6.2.1), with its
/// mailbox at unit id 101.
fn ascii_config(port: &Path) -> String {
    head()
        + &format!(
            r#"
[lines.ascii]
port = "{port}"
protocol = "ascii"
baud = 9600
parity = "even"
end_criterion = "char-delay"
character_delay = "20ms"
unit_id = 101
"#,
            port = port.display()
        )
}

/// The oldest waiting telegram of the mailbox (STATUS, SEQ, LEN at 0..2, data from 4, high byte
/// first), acknowledged at 600 once read. `None` if none arrived within 5 s.
async fn take_telegram(ctx: &mut Context) -> Option<Vec<u8>> {
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let head = ctx
            .read_holding_registers(0, 20)
            .await
            .expect("transport")
            .expect("the receive block");
        let (seq, len) = (head[1], usize::from(head[2]));
        if seq != 0 {
            let data: Vec<u8> = head[4..]
                .iter()
                .flat_map(|w| w.to_be_bytes())
                .take(len)
                .collect();
            ctx.write_single_register(600, seq)
                .await
                .expect("transport")
                .expect("acknowledge");
            return Some(data);
        }
        if Instant::now() >= deadline {
            return None;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// 003 6.2 (full duplex): while the gateway sends a long telegram, the partner's two telegrams,
/// 60 ms apart (three times the character delay time), stay two telegrams. A receiver that timed
/// the partner's bytes from the end of its own transmission would see no gap and merge them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_ascii_line_keeps_the_partners_telegrams_apart_while_it_sends_a_long_one() {
    let dir = temp_dir("peer-ascii-duplex");
    let link = SocatLink::new(&dir, "ascii");
    let gw = start_gateway(&dir, &ascii_config(&link.a));
    let mut port = open(&link.b, 9600);
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(101))
        .await
        .expect("connect");
    // 200 bytes take 229 ms at 9600 Bd 8E1: the gateway's own transmission while the partner
    // sends.
    let long = vec![b'L'; 200];
    mailbox_send(&mut ctx, 1, &long).await;
    assert!(
        read_byte(&mut port, Duration::from_secs(20))
            .await
            .is_some(),
        "the gateway's telegram did not start"
    );
    port.write_all(b"AAAA").await.expect("write");
    tokio::time::sleep(Duration::from_millis(60)).await;
    port.write_all(b"BBBB").await.expect("write");
    let first = take_telegram(&mut ctx).await;
    let second = take_telegram(&mut ctx).await;
    assert_eq!(
        (first.as_deref(), second.as_deref()),
        (Some(&b"AAAA"[..]), Some(&b"BBBB"[..])),
        "two telegrams, in order"
    );
    let (done, error, _) = mailbox_result(&mut ctx, 1).await;
    assert_eq!((done, error), (1, 0), "the gateway's own telegram was sent");
    drop(gw);
    drop(link);
}
