//! `gateway scan`: which slave addresses answer on a serial bus, and who they are.
//!
//! Each address of the range gets one FC 03 read of holding register 0: a response or an
//! exception means a device is there (an exception is an answer: the device heard its address).
//! A device that answered is asked who it is, with FC 43/14 "read device identification" (basic
//! objects: vendor, product code, revision; Modbus Application Protocol V1.1b3, 6.21) and, where
//! it does not give that, FC 17 "report server ID" (6.13).
//!
//! Why it is built this way: the scan is a Modbus master line with no devices, the gateway's own
//! ([`crate::protocols::spawn_modbus_master_line`]): the proto-core master engine, the port opened by
//! [`crate::serial::open`] with the line's frame, the same RTU timing and reply monitoring; a
//! request to an address without a device is an ordinary command. Before the line starts, the
//! port is opened once to see whether another process holds it: a running gateway opens its
//! ports exclusively (`TIOCEXCL` and an exclusive `flock`, the serial library's exclusive mode),
//! and a scan on its bus would collide with its polls, so the scan refuses such a port and says
//! so.

use std::fmt::Write as _;
use std::io::{IsTerminal as _, Write as _};
use std::time::Duration;

use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use crate::image::ProcessImage;
use crate::line;
use crate::protocols::REPLY_TIMEOUT_RANGE;
use crate::protocols::{CommandError, LineClient, LineSettings, QueueError};
use crate::serial::{self, OpenError, PortSettings, StopBits};
use crate::sim::Parity;

/// Addresses a slave may have (Modbus over Serial Line V1.02, 2.2: 1..247).
const SLAVE_ADDRESSES: std::ops::RangeInclusive<u8> = 1..=247;
/// How long the scan waits for its line to open the port.
const OPEN_WAIT: Duration = Duration::from_secs(5);
/// MEI type 14 read code 01: the basic identification objects (Modbus Application Protocol
/// V1.1b3, 6.21).
const BASIC_IDENTIFICATION: u8 = 0x01;

/// `gateway scan` arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct ScanArgs {
    /// The serial port of the bus.
    #[arg(long)]
    pub port: String,
    /// Baud rate.
    #[arg(long)]
    pub baud: u32,
    /// Parity (8 data bits, Modbus RTU).
    #[arg(long, value_enum, default_value_t = Parity::Even)]
    pub parity: Parity,
    /// Stop bits (1 or 2).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub stop_bits: u8,
    /// First address asked.
    #[arg(long, default_value_t = 1)]
    pub from: u8,
    /// Last address asked.
    #[arg(long, default_value_t = 247)]
    pub to: u8,
    /// Reply monitoring time of each request (5ms..65500ms).
    #[arg(long, default_value = "100ms", value_parser = humantime::parse_duration)]
    pub timeout: Duration,
    /// Print a TOML document with a device block for each address found instead.
    #[arg(long)]
    pub toml: bool,
    /// With --toml: the blocks' headers name this line (`[lines.NAME.devices.D]`), ready to
    /// append to a config; without it they are `[devices.D]`, the line's `devices` table.
    #[arg(long, value_name = "NAME")]
    pub line: Option<String>,
}

/// Why the scan could not run.
#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    /// Arguments out of range.
    #[error("{0}")]
    Usage(String),
    /// Another process holds the port.
    #[error(
        "port {0} is in use by another process: a running gateway (or another program) holds it \
         exclusively (TIOCEXCL and flock); stop that line or that program first, a scan would \
         collide with its traffic"
    )]
    Busy(String),
    /// The port could not be opened.
    #[error("{0}")]
    Open(#[from] OpenError),
    /// The line's port closed during the scan.
    #[error("port {0} closed during the scan")]
    PortLost(String),
}

/// What one address answered.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Found {
    /// The slave address.
    pub address: u8,
    /// The FC 03 read: `None` values, `Some(code)` the exception it answered.
    pub exception: Option<ExceptionCode>,
    /// What it says it is, if it says.
    pub identity: Option<Identity>,
}

/// A device's own description.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Identity {
    /// FC 43/14 objects, id and text.
    Objects(Vec<(u8, String)>),
    /// FC 17 bytes (server id, run indicator, device-specific data).
    ServerId(Vec<u8>),
}

// === impl ScanArgs ===

impl ScanArgs {
    fn check(&self) -> Result<(), ScanError> {
        for (name, address) in [("--from", self.from), ("--to", self.to)] {
            if !SLAVE_ADDRESSES.contains(&address) {
                return Err(ScanError::Usage(format!(
                    "{name} {address} is outside 1..=247 (Modbus over Serial Line V1.02 2.2)"
                )));
            }
        }
        if self.from > self.to {
            return Err(ScanError::Usage(format!(
                "--from {} is after --to {}",
                self.from, self.to
            )));
        }
        let (lo, hi) = REPLY_TIMEOUT_RANGE;
        if !(lo..=hi).contains(&self.timeout) {
            return Err(ScanError::Usage(format!(
                "--timeout {:?} is outside 5ms..65500ms (003 6.4.2.1 reply monitoring time)",
                self.timeout
            )));
        }
        if self.baud == 0 {
            return Err(ScanError::Usage("--baud must be above 0".into()));
        }
        Ok(())
    }

    fn port_settings(&self) -> PortSettings {
        let mut port = PortSettings::new(&self.port, self.baud);
        port.parity = match self.parity {
            Parity::None => serial::Parity::None,
            Parity::Odd => serial::Parity::Odd,
            Parity::Even => serial::Parity::Even,
        };
        port.stop_bits = if self.stop_bits == 2 {
            StopBits::Two
        } else {
            StopBits::One
        };
        port.monitor_frames = 0;
        port
    }
}

/// Logging of the scan: errors only unless `RUST_LOG` says otherwise (stderr shows the progress;
/// the line's own INFO lines would only clutter it).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("error"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

/// Runs `gateway scan`; the exit code: 0, 64 (sysexits.h EX_USAGE) on a usage error, 1 when the
/// scan failed, with the error on stderr.
pub async fn command(args: ScanArgs, shutdown: CancellationToken) -> u8 {
    let Err(e) = run(args, shutdown).await else {
        return 0;
    };
    eprintln!("gateway scan: {e}");
    if matches!(e, ScanError::Usage(_)) {
        64 // sysexits.h EX_USAGE
    } else {
        1
    }
}

/// Scans the bus and prints what answers on stdout (a line per address, or TOML with
/// `--toml`); progress on stderr when it is a terminal. Stops early when `shutdown` is
/// cancelled, printing what it found so far.
pub async fn run(args: ScanArgs, shutdown: CancellationToken) -> Result<(), ScanError> {
    args.check()?;
    let port = args.port_settings();
    // Open once, as the line will: a port another process holds exclusively is refused here.
    match serial::open(&port) {
        Ok(stream) => drop(stream),
        Err(e) if e.is_busy() => return Err(ScanError::Busy(args.port.clone())),
        Err(e) => return Err(e.into()),
    }
    let mut settings = LineSettings::rtu("scan", port);
    settings.master.reply_timeout = args.timeout;
    settings.master.retries = 0;
    settings.queue_depth = 2;
    let line_stop = CancellationToken::new();
    let handle = crate::protocols::spawn_modbus_master_line(
        settings,
        Vec::new(),
        ProcessImage::default(),
        line_stop.clone(),
    );
    let result = scan(&args, &handle, &shutdown).await;
    line_stop.cancel();
    handle.join().await;
    let found = result?;
    // A closed stdout (`| head`) ends the output quietly: what was found is printed or not.
    let mut out = std::io::stdout().lock();
    if args.toml {
        let _ = write!(out, "{}", toml_document(&args, &found));
    } else {
        for f in &found {
            let _ = writeln!(out, "{}", describe(f));
        }
    }
    let _ = out.flush();
    Ok(())
}

async fn scan(
    args: &ScanArgs,
    handle: &line::LineHandle,
    shutdown: &CancellationToken,
) -> Result<Vec<Found>, ScanError> {
    let lost = || ScanError::PortLost(args.port.clone());
    let client = handle.client().ok_or_else(lost)?;
    let opened = Instant::now();
    while !handle.status().port_open {
        if opened.elapsed() > OPEN_WAIT {
            return Err(lost());
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let progress = std::io::stderr().is_terminal();
    let total = usize::from(args.to - args.from) + 1;
    let started = Instant::now();
    let mut found = Vec::new();
    let mut garbled = Vec::new();
    for (done, address) in (args.from..=args.to).enumerate() {
        if shutdown.is_cancelled() {
            break;
        }
        if progress {
            show_progress(address, done, total, started.elapsed(), args.timeout);
        }
        let read = Request::ReadHoldingRegisters {
            address: 0,
            quantity: 1,
        };
        let exception = match ask(&client, address, read).await {
            Asked::Answer(_) => None,
            Asked::Exception(code) => Some(code),
            Asked::Silent => continue,
            Asked::Garbled => {
                garbled.push(address);
                continue;
            }
            Asked::Lost => return Err(lost()),
        };
        let identity = identify(&client, address).await.ok_or_else(lost)?;
        found.push(Found {
            address,
            exception,
            identity,
        });
    }
    if progress {
        eprint!("\r\x1b[K");
    }
    if !garbled.is_empty() {
        eprintln!(
            "gateway scan: replies that failed their checks (CRC, length, address) came for \
             addresses {garbled:?}: a device with another baud rate or parity, or two devices \
             at one address"
        );
    }
    Ok(found)
}

/// One line of progress: the address asked and the time left at the pace so far (the reply
/// monitoring time per address before the first one is done).
fn show_progress(address: u8, done: usize, total: usize, elapsed: Duration, timeout: Duration) {
    let per = if done == 0 {
        timeout
    } else {
        elapsed / u32::try_from(done).unwrap_or(u32::MAX)
    };
    let left = per.saturating_mul(u32::try_from(total - done).unwrap_or(u32::MAX));
    eprint!(
        "\r\x1b[Kscanning address {address} ({} of {total}), about {:.0} s left",
        done + 1,
        left.as_secs_f64().ceil()
    );
}

/// What one request got.
enum Asked {
    Answer(Response),
    Exception(ExceptionCode),
    /// No reply within the reply monitoring time.
    Silent,
    /// Something answered, but not a valid reply.
    Garbled,
    /// The port closed.
    Lost,
}

async fn ask(client: &LineClient, address: u8, request: Request) -> Asked {
    // One request at a time; the previous one's place in the queue is freed just after its
    // answer arrives, so a full queue is a moment to wait, a closed one the end.
    let rx = loop {
        match client.try_submit(address, request.clone()) {
            Ok(rx) => break rx,
            Err(QueueError::Full) => tokio::time::sleep(Duration::from_millis(1)).await,
            Err(QueueError::Closed) => return Asked::Lost,
        }
    };
    match rx.await {
        Ok(Ok(Ok(response))) => Asked::Answer(response),
        Ok(Ok(Err(code))) => Asked::Exception(code),
        Ok(Err(CommandError::NoReply { event, .. }))
            if event == proto_core::event::ids::MODBUS_NO_REPLY =>
        {
            Asked::Silent
        }
        Ok(Err(CommandError::NoReply { .. })) => Asked::Garbled,
        // An address the engine refuses, or offline rules: nothing there to report.
        Ok(Err(CommandError::Refused(_) | CommandError::Offline(_))) => Asked::Silent,
        Ok(Err(CommandError::PortClosed | CommandError::ShuttingDown)) | Err(_) => Asked::Lost,
    }
}

/// FC 43/14 basic objects, else FC 17, else nothing (`Some(None)`); `None` when the port closed.
async fn identify(client: &LineClient, address: u8) -> Option<Option<Identity>> {
    let read = Request::ReadDeviceIdentification {
        read_code: BASIC_IDENTIFICATION,
        object_id: 0,
    };
    match ask(client, address, read).await {
        Asked::Answer(Response::ReadDeviceIdentification { objects, .. })
            if !objects.is_empty() =>
        {
            let objects = objects
                .into_iter()
                .map(|(id, bytes)| (id, String::from_utf8_lossy(&bytes).trim().to_owned()))
                .collect();
            return Some(Some(Identity::Objects(objects)));
        }
        Asked::Lost => return None,
        _ => {}
    }
    match ask(client, address, Request::ReportServerId).await {
        Asked::Answer(Response::ReportServerId(bytes)) if !bytes.is_empty() => {
            Some(Some(Identity::ServerId(bytes)))
        }
        Asked::Lost => None,
        _ => Some(None),
    }
}

/// The name of an FC 43 basic or regular object (Modbus Application Protocol V1.1b3, 6.21,
/// table of object ids).
fn object_name(id: u8) -> Option<&'static str> {
    Some(match id {
        0x00 => "vendor",
        0x01 => "product code",
        0x02 => "revision",
        0x03 => "vendor url",
        0x04 => "product name",
        0x05 => "model name",
        0x06 => "user application name",
        _ => return None,
    })
}

// === impl Identity ===

impl Identity {
    /// `vendor "Telemecanique", product code "ATV71HU15M3", ...` or `server id 11h, run
    /// indicator ON, data "..."`.
    pub fn describe(&self) -> String {
        match self {
            Self::Objects(objects) => objects
                .iter()
                .map(|(id, text)| match object_name(*id) {
                    Some(name) => format!("{name} {text:?}"),
                    None => format!("object {id:02X}h {text:?}"),
                })
                .collect::<Vec<_>>()
                .join(", "),
            Self::ServerId(bytes) => {
                let mut s = String::new();
                if let Some(id) = bytes.first() {
                    let _ = write!(s, "server id {id:02X}h");
                }
                // 6.13: the run indicator status, 00h OFF, FFh ON.
                match bytes.get(1) {
                    Some(0xFF) => s.push_str(", run indicator ON"),
                    Some(0x00) => s.push_str(", run indicator OFF"),
                    _ => {}
                }
                if let Some(rest) = bytes.get(2..).filter(|r| !r.is_empty()) {
                    let text: String = rest
                        .iter()
                        .map(|&b| {
                            if b.is_ascii_graphic() || b == b' ' {
                                char::from(b)
                            } else {
                                '.'
                            }
                        })
                        .collect();
                    let _ = write!(s, ", data {:?}", text.trim());
                }
                s
            }
        }
    }
}

/// One output line: the address first, then what it answered, then its identity.
pub fn describe(found: &Found) -> String {
    let answer = match found.exception {
        None => "registers".to_owned(),
        Some(code) => format!("exception {:02X}", u8::from(code)),
    };
    match &found.identity {
        Some(identity) => format!("{} {answer}: {}", found.address, identity.describe()),
        None => format!("{} {answer}", found.address),
    }
}

/// The TOML document of `--toml`: a device block for each address found.
pub fn toml_document(args: &ScanArgs, found: &[Found]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# gateway scan --port {} --baud {}: {} of addresses {}..={} answered",
        args.port,
        args.baud,
        found.len(),
        args.from,
        args.to
    );
    for f in found {
        let name = format!("device_{}", f.address);
        let header = match &args.line {
            Some(line) => format!("lines.{}.devices.{name}", toml_key(line)),
            None => format!("devices.{name}"),
        };
        let _ = writeln!(out, "\n[{header}]");
        if let Some(identity) = &f.identity {
            let _ = writeln!(out, "# {}", identity.describe().replace('\n', " "));
        }
        let _ = writeln!(out, "address = {}", f.address);
        let profile = profile_of(f.identity.as_ref());
        let _ = writeln!(out, "profile = \"{}\"", profile.unwrap_or("generic"));
        if profile.is_none() {
            let exception = f
                .exception
                .map(|code| format!(" exception {:02X}", u8::from(code)))
                .unwrap_or_default();
            let _ = writeln!(
                out,
                "# holding register 0 answered{exception}; replace with the device's tags\n\
                 tags = [{{ name = \"register_0\", table = \"holding\", address = 0 }}]"
            );
        }
    }
    out
}

/// A built-in profile for a device whose FC 43 identity names it.
fn profile_of(identity: Option<&Identity>) -> Option<&'static str> {
    let Some(Identity::Objects(objects)) = identity else {
        return None;
    };
    let text = |id: u8| {
        objects
            .iter()
            .find(|(i, _)| *i == id)
            .map(|(_, t)| t.to_ascii_uppercase())
            .unwrap_or_default()
    };
    let (vendor, product) = (text(0x00), text(0x01));
    if (vendor.contains("TELEMECANIQUE") || vendor.contains("SCHNEIDER"))
        && (product.starts_with("ATV71") || product.starts_with("ATV61"))
    {
        Some("altivar71")
    } else if vendor.contains("PMA") && product.contains("KS") {
        Some("ksvario")
    } else {
        None
    }
}

/// A line name as a TOML key: bare when it can be, quoted otherwise.
fn toml_key(name: &str) -> String {
    if !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        name.to_owned()
    } else {
        format!("{name:?}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args() -> ScanArgs {
        ScanArgs {
            port: "/dev/ttyUSB0".into(),
            baud: 19200,
            parity: Parity::Even,
            stop_bits: 1,
            from: 1,
            to: 247,
            timeout: Duration::from_millis(100),
            toml: true,
            line: None,
        }
    }

    fn altivar(address: u8) -> Found {
        Found {
            address,
            exception: Some(ExceptionCode::IllegalDataAddress),
            identity: Some(Identity::Objects(vec![
                (0, "Telemecanique".into()),
                (1, "ATV71HU15M3".into()),
                (2, "0201".into()),
            ])),
        }
    }

    #[test]
    fn a_line_starts_with_the_address_and_names_the_identity() {
        assert_eq!(
            describe(&altivar(2)),
            "2 exception 02: vendor \"Telemecanique\", product code \"ATV71HU15M3\", revision \"0201\""
        );
        let plain = Found {
            address: 40,
            exception: None,
            identity: Some(Identity::ServerId(vec![0x11, 0xFF, b'K', b'S'])),
        };
        assert_eq!(
            describe(&plain),
            "40 registers: server id 11h, run indicator ON, data \"KS\""
        );
    }

    #[test]
    fn the_toml_document_parses_with_one_device_per_address() {
        let unknown = Found {
            address: 9,
            exception: None,
            identity: None,
        };
        let doc = toml_document(&args(), &[altivar(2), unknown.clone()]);
        let value: toml::Table = toml::from_str(&doc).expect("valid TOML");
        let devices = value
            .get("devices")
            .and_then(toml::Value::as_table)
            .expect("devices");
        assert_eq!(devices.len(), 2);
        let d2 = devices.get("device_2").expect("device_2");
        assert_eq!(d2.get("address").and_then(toml::Value::as_integer), Some(2));
        assert_eq!(
            d2.get("profile").and_then(toml::Value::as_str),
            Some("altivar71")
        );
        let d9 = devices.get("device_9").expect("device_9");
        assert_eq!(
            d9.get("profile").and_then(toml::Value::as_str),
            Some("generic")
        );
        let mut named = args();
        named.line = Some("bus".into());
        let doc = toml_document(&named, &[unknown]);
        let value: toml::Table = toml::from_str(&doc).expect("valid TOML");
        assert!(value
            .get("lines")
            .and_then(|l| l.get("bus"))
            .and_then(|b| b.get("devices"))
            .and_then(|d| d.get("device_9"))
            .is_some());
    }

    #[test]
    fn bad_ranges_are_refused_with_the_reason() {
        let mut a = args();
        a.from = 0;
        assert!(a.check().is_err_and(|e| e.to_string().contains("--from 0")));
        let mut a = args();
        a.from = 20;
        a.to = 10;
        assert!(a.check().is_err_and(|e| e.to_string().contains("after")));
        let mut a = args();
        a.timeout = Duration::from_millis(1);
        assert!(a
            .check()
            .is_err_and(|e| e.to_string().contains("--timeout")));
    }
}
