//! The 32-bit register mode of a Modbus master ASCII line (003 6.4.4), end to end: the gateway
//! binary runs a config with `registers32 = true` on one end of a real pty pair, a slave written
//! here serves 32-bit holding registers on the other end, and a Modbus TCP client reads and writes
//! them as pairs of 16-bit registers.
//!
//! The slave uses proto-core's ASCII framing only; it decodes the 32-bit PDUs itself (a read
//! request is the 16-bit one, the answer carries 4 bytes a register; a write carries 4 bytes a
//! register) and records which of 43h, 46h and 50h it served.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use proto_core::modbus::ascii::{decode_frame, encode_frame};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_modbus::client::{tcp, Reader, Writer};
use tokio_modbus::prelude::Slave;
use tokio_serial::{SerialPort, SerialStream};

/// The slave address of the 32-bit device.
const SLAVE: u8 = 5;
/// How long the gateway may take to come up and poll.
const TIMEOUT: Duration = Duration::from_secs(30);

/// The 32-bit registers of the slave and the 32-bit functions it served.
#[derive(Debug, Default)]
struct Registers32 {
    values: BTreeMap<u16, u32>,
    served: Vec<u8>,
}

/// The answer PDU to `pdu`, `None` for a function this slave does not serve.
fn answer(regs: &Mutex<Registers32>, pdu: &[u8]) -> Option<Vec<u8>> {
    let mut regs = regs.lock().expect("registers");
    let word = |at: usize| Some(u16::from_be_bytes([*pdu.get(at)?, *pdu.get(at + 1)?]));
    let long = |at: usize| {
        Some(u32::from_be_bytes([
            *pdu.get(at)?,
            *pdu.get(at + 1)?,
            *pdu.get(at + 2)?,
            *pdu.get(at + 3)?,
        ]))
    };
    let exception = |code: u8| Some(vec![pdu.first()? | 0x80, code]);
    match *pdu.first()? {
        // 43h: a 16-bit read request, 4 bytes a register in the answer.
        0x03 if pdu.len() == 5 => {
            let (address, quantity) = (word(1)?, word(3)?);
            let values: Option<Vec<u32>> = (address..address.checked_add(quantity)?)
                .map(|a| regs.values.get(&a).copied())
                .collect();
            let Some(values) = values else {
                return exception(0x02);
            };
            regs.served.push(0x43);
            let mut out = vec![0x03, u8::try_from(values.len() * 4).ok()?];
            for v in values {
                out.extend_from_slice(&v.to_be_bytes());
            }
            Some(out)
        }
        // 46h: address and a 4-byte value, echoed.
        0x06 if pdu.len() == 7 => {
            regs.values.insert(word(1)?, long(3)?);
            regs.served.push(0x46);
            Some(pdu.to_vec())
        }
        // 50h: address, quantity, byte count 4 x quantity, the values.
        0x10 => {
            let (address, quantity) = (word(1)?, word(3)?);
            if usize::from(*pdu.get(5)?) != usize::from(quantity) * 4
                || pdu.len() != 6 + usize::from(quantity) * 4
            {
                return exception(0x03);
            }
            for i in 0..quantity {
                regs.values
                    .insert(address + i, long(6 + usize::from(i) * 4)?);
            }
            regs.served.push(0x50);
            Some(pdu.get(..5)?.to_vec())
        }
        _ => exception(0x01),
    }
}

/// Serves ASCII frames for [`SLAVE`] on `port` until it fails.
async fn run_slave(mut port: SerialStream, regs: Arc<Mutex<Registers32>>) {
    let mut buf: Vec<u8> = Vec::new();
    let mut chunk = [0u8; 256];
    loop {
        let n = match port.read(&mut chunk).await {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        buf.extend_from_slice(&chunk[..n]);
        while let Some(end) = buf.windows(2).position(|w| w == b"\r\n") {
            let frame: Vec<u8> = buf.drain(..end + 2).collect();
            let Some(start) = frame.iter().position(|b| *b == b':') else {
                continue;
            };
            let Ok((address, pdu)) = decode_frame(&frame[start..]) else {
                continue;
            };
            if address != SLAVE {
                continue;
            }
            let Some(reply) = answer(&regs, &pdu) else {
                continue;
            };
            let mut out = Vec::new();
            encode_frame(SLAVE, &reply, &mut out);
            if port.write_all(&out).await.is_err() {
                return;
            }
        }
    }
}

/// The gateway process, killed when dropped.
struct Gateway {
    child: Child,
    lines: mpsc::Receiver<String>,
}

impl Gateway {
    /// Starts `gateway run --config <config>` and returns it with its Modbus TCP and HTTP
    /// addresses.
    fn start(
        config: &std::path::Path,
    ) -> (Self, std::net::SocketAddr, Option<std::net::SocketAddr>) {
        let mut child = Command::new(env!("CARGO_BIN_EXE_gateway"))
            .args(["run", "--config"])
            .arg(config)
            .args(["--http", "127.0.0.1:0"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start the gateway");
        let (tx, lines) = mpsc::channel();
        for stream in [
            Box::new(child.stdout.take().expect("stdout")) as Box<dyn std::io::Read + Send>,
            Box::new(child.stderr.take().expect("stderr")),
        ] {
            let tx = tx.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stream).lines().map_while(Result::ok) {
                    let _ = tx.send(line);
                }
            });
        }
        let gw = Self { child, lines };
        let deadline = Instant::now() + TIMEOUT;
        let mut seen = Vec::new();
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let line = gw
                .lines
                .recv_timeout(left)
                .unwrap_or_else(|_| panic!("no Modbus TCP announcement; output:\n{seen:#?}"));
            if let Some((_, addr)) = line.split_once("modbus-tcp listening on ") {
                let addr = addr.trim().parse().expect("Modbus TCP address");
                // The HTTP line comes first, on the same stream.
                let http = seen.iter().find_map(|l: &String| {
                    l.split_once("http listening on ")
                        .and_then(|(_, a)| a.trim().parse().ok())
                });
                return (gw, addr, http);
            }
            seen.push(line);
        }
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn config(port: &str) -> String {
    format!(
        r#"
[gateway]
name = "registers32"

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
insecure_allow_unauthenticated_changes = true

[lines.meters]
port = "{port}"
baud = 19200
data_bits = 8
parity = "even"
stop_bits = 1
protocol = "modbus-master-ascii"
reply_timeout = "500ms"
registers32 = true

[lines.meters.devices.meter]
profile = "generic"
address = {SLAVE}
unit_id = {SLAVE}

[[lines.meters.devices.meter.tags]]
name = "counter"
table = "holding"
address = 0
type = "u32"
writable = true

[[lines.meters.devices.meter.tags]]
name = "level"
table = "holding"
address = 2
type = "f32"
writable = true

# Bit 3 of image register 5: the low half of slave register 2.
[[lines.meters.devices.meter.tags]]
name = "relay"
table = "holding"
address = 5
bit = 3
writable = true

[[lines.meters.devices.meter.poll]]
name = "all"
period = "100ms"
tags = ["counter", "level"]
"#
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_32_bit_master_ascii_line_reads_and_writes_32_bit_registers_as_register_pairs() {
    let (slave_end, line_end) = SerialStream::pair().expect("pty pair");
    let path = line_end.name().expect("pty path");
    let regs = Arc::new(Mutex::new(Registers32::default()));
    {
        let mut r = regs.lock().expect("registers");
        r.values.insert(0, 0x1234_5678);
        r.values.insert(1, 222.0f32.to_bits());
        r.values.insert(2, 0x1234_0001);
    }
    let slave = tokio::spawn(run_slave(slave_end, Arc::clone(&regs)));

    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("gateway.toml");
    std::fs::write(&file, config(&path)).expect("write config");
    let (gw, addr, http) = Gateway::start(&file);

    let mut ctx = tcp::connect_slave(addr, Slave(SLAVE))
        .await
        .expect("connect to the gateway");
    // Slave register 0 is image registers 0 (high) and 1 (low), register 1 is 2 and 3.
    let deadline = Instant::now() + TIMEOUT;
    let words = loop {
        match ctx.read_holding_registers(0, 4).await.expect("transport") {
            Ok(words) => break words,
            Err(e) => assert!(Instant::now() < deadline, "no poll answer: {e:?}"),
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(words, [0x1234, 0x5678, 0x435E, 0x0000]);

    // Two image registers are one 32-bit register: 46h. Four are two: 50h.
    ctx.write_multiple_registers(2, &[0xDEAD, 0xBEEF])
        .await
        .expect("transport")
        .expect("write of one 32-bit register");
    ctx.write_multiple_registers(0, &[0x0001, 0x0002, 0x4120, 0x0000])
        .await
        .expect("transport")
        .expect("write of two 32-bit registers");
    // Half a 32-bit register cannot be written.
    assert!(ctx
        .write_single_register(0, 7)
        .await
        .expect("transport")
        .is_err());
    {
        let r = regs.lock().expect("registers");
        assert_eq!(r.values.get(&0), Some(&0x0001_0002));
        assert_eq!(r.values.get(&1), Some(&10.0f32.to_bits()));
        for function in [0x43, 0x46, 0x50] {
            assert!(
                r.served.contains(&function),
                "{function:02X}h not served: {:02X?}",
                r.served
            );
        }
    }
    // The next poll reads the written values back into the image.
    let deadline = Instant::now() + TIMEOUT;
    loop {
        let words = ctx
            .read_holding_registers(0, 4)
            .await
            .expect("transport")
            .expect("read");
        if words == [0x0001, 0x0002, 0x4120, 0x0000] {
            break;
        }
        assert!(Instant::now() < deadline, "image still {words:04X?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }

    // A bit tag: the read-modify-write reads the whole 32-bit register (43h) and writes it back
    // with only its bit changed (46h); the other half and the other bits stay.
    let http = http.expect("the gateway serves HTTP");
    let url = format!("http://{http}/api/v1/lines/meters/devices/meter/tags/relay");
    let answer = reqwest::Client::new()
        .put(&url)
        .json(&serde_json::json!({ "value": true }))
        .send()
        .await
        .expect("PUT the bit tag");
    let status = answer.status();
    let body = answer.text().await.unwrap_or_default();
    assert!(status.is_success(), "{status}: {body}");
    assert_eq!(
        regs.lock().expect("registers").values.get(&2),
        Some(&0x1234_0009)
    );
    // Half of an unpolled 32-bit register read on demand: the whole register is read (43h), the
    // client gets its half.
    let low = ctx
        .read_holding_registers(5, 1)
        .await
        .expect("transport")
        .expect("read of half a register");
    assert_eq!(low, [0x0009]);
    slave.abort();
    drop(line_end);
    drop(gw);
}
