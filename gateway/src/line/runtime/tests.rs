use std::collections::VecDeque;

use tokio::io::DuplexStream;

use super::task::Which;
use super::*;
use crate::line::testing::{events, eventually, Ports};

/// Echoes what it receives and writes what it is sent as a command.
struct Echo {
    shared: Arc<Shared>,
    out: VecDeque<Vec<u8>>,
    refused: Arc<Mutex<Vec<Vec<u8>>>>,
}

impl LineEngine for Echo {
    fn opened(&mut self, modem: Option<&mut dyn SerialPort>) {
        assert!(modem.is_none(), "an in-process stream has no modem lines");
        self.out.clear();
    }

    fn handle_rx(&mut self, _now: proto_core::time::Instant, bytes: &[u8]) {
        self.out.push_back(bytes.to_vec());
    }

    fn handle_line_error(&mut self, _now: proto_core::time::Instant, error: LineError) {
        self.out.push_back(format!("<{error:?}>").into_bytes());
    }

    fn handle_timeout(&mut self, _now: proto_core::time::Instant) {}

    fn poll_timeout(&self) -> Option<proto_core::time::Instant> {
        None
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.out.pop_front()
    }

    fn transmitted(&mut self, _at: Instant, _len: usize, _end: proto_core::time::Instant) {
        self.shared.metrics().sent_telegram();
    }

    fn handle_events(&mut self) -> bool {
        false
    }
}

impl LineCommands for Echo {
    type Command = Vec<u8>;

    fn command(&mut self, command: Vec<u8>, _modem: Option<&mut dyn SerialPort>) {
        self.out.push_back(command);
    }

    fn refuse(&mut self, command: Vec<u8>, _shutting_down: bool) {
        self.refused
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push(command);
    }
}

impl LineLifecycle for Echo {
    fn stop(&mut self) -> Stop {
        Stop {
            read: true,
            close_queue: true,
            grace: None,
        }
    }

    fn done(&self) -> bool {
        self.out.is_empty()
    }

    fn closed(&mut self, _shutting_down: bool) {}

    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.raise(id, None, Some(reason));
    }
}

impl LineSignals for Echo {}

impl SecondPort for Echo {}

#[derive(Debug)]
struct Nothing;

impl LineCapabilities for Nothing {
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// The core of a test line named `name` on `path` (diag depth 8, reopen after 10 to 20 ms,
/// no metrics) and its `Echo` engine.
fn echo_line(name: &str, path: &str) -> (LineCore, Echo) {
    let base = LineBase::new(
        name,
        "echo",
        &PortSettings::new(path, 9600),
        8,
        (Duration::from_millis(10), Duration::from_millis(20)),
        None,
    );
    let core = base.core(Vec::new());
    let engine = Echo {
        shared: Arc::clone(&core.shared),
        out: VecDeque::new(),
        refused: Arc::new(Mutex::new(Vec::new())),
    };
    (core, engine)
}

#[tokio::test]
async fn a_line_on_an_in_process_stream_opens_echoes_reopens_and_stops() {
    let (port, mut partner) = tokio::io::duplex(64);
    let opener = Ports(Mutex::new(VecDeque::from([
        Err("busy".to_owned()),
        Ok(port),
    ])));
    let (core, engine) = echo_line("echo", "/dev/in-process");
    let refused = Arc::clone(&engine.refused);
    let (tx, rx) = mpsc::channel(4);
    let shutdown = CancellationToken::new();
    let line = spawn(
        core,
        engine,
        Some(rx),
        Arc::new(Nothing),
        opener,
        shutdown.clone(),
    );
    assert_eq!((line.name(), line.protocol()), ("echo", "echo"));

    // The first opening fails (02 0Fh), the second after the back-off succeeds.
    eventually("the port open", || line.status().port_open).await;
    assert_eq!(events(&line, EVENT_PORT_SETUP), 1);
    assert_eq!(events(&line, ids::PTP_PARAMS_ACCEPTED), 1);

    // Bytes in, the engine's answer out; a command out.
    partner.write_all(b"hello").await.expect("write");
    let mut echo = [0u8; 5];
    partner.read_exact(&mut echo).await.expect("echo");
    assert_eq!(&echo, b"hello");
    tx.send(b"cmd".to_vec()).await.expect("queue");
    let mut cmd = [0u8; 3];
    partner.read_exact(&mut cmd).await.expect("command");
    assert_eq!(&cmd, b"cmd");
    let traffic = line.traffic();
    assert_eq!(
        (
            traffic.bytes_received,
            traffic.bytes_sent,
            traffic.frames_sent
        ),
        (5, 8, 2)
    );

    // The partner goes: 08 0Dh, then every reopening fails while commands are refused.
    drop(partner);
    eventually("the port lost", || events(&line, EVENT_PORT_LOST) == 1).await;
    eventually("a failed reopening", || {
        events(&line, EVENT_PORT_SETUP) >= 2
    })
    .await;
    let status = line.status();
    assert!(!status.port_open);
    assert_eq!(status.port_error.as_deref(), Some("no such port"));
    tx.send(b"late".to_vec()).await.expect("queue");
    eventually("the late command refused", || {
        refused.lock().unwrap_or_else(PoisonError::into_inner).len() == 1
    })
    .await;

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(2), line.join())
        .await
        .expect("the line stops");
    assert!(tx.send(b"after".to_vec()).await.is_err(), "queue closed");
}

#[tokio::test]
async fn the_port_layer_records_every_frame_into_the_monitor() {
    let (port, mut partner) = tokio::io::duplex(64);
    let opener = Ports(Mutex::new(VecDeque::from([Ok(port)])));
    let (core, engine) = echo_line("monitored", "/dev/in-process");
    let shutdown = CancellationToken::new();
    let line = spawn(
        core,
        engine,
        None,
        Arc::new(Nothing),
        opener,
        shutdown.clone(),
    );
    eventually("the port open", || line.status().port_open).await;
    let monitor = Arc::clone(line.monitor().expect("a monitor by default"));

    // Bytes in with a parity mark inside (one read), the echo out piece by piece: the first
    // transmission ends the received frame, which carries the line error at its place.
    partner
        .write_all(&[b'h', b'i', 0xFF, 0x00, b'x', b'!'])
        .await
        .expect("write");
    let expected: &[u8] = b"hi<ParityOrFraming>!";
    let mut echo = vec![0u8; expected.len()];
    partner.read_exact(&mut echo).await.expect("echo");
    eventually("four frames", || monitor.frames_since(0).0.len() == 4).await;
    let (frames, next) = monitor.frames_since(0);
    assert_eq!(next, 5);
    assert_eq!(
        frames
            .iter()
            .map(|f| (f.direction, f.bytes.clone()))
            .collect::<Vec<_>>(),
        [
            (Direction::Rx, b"hi!".to_vec()),
            (Direction::Tx, b"hi".to_vec()),
            (Direction::Tx, b"<ParityOrFraming>".to_vec()),
            (Direction::Tx, b"!".to_vec()),
        ]
    );
    assert_eq!(frames[0].errors.len(), 1);
    assert_eq!(frames[0].errors[0].offset, 2);
    assert!(frames[0].first_mono <= frames[0].last_mono);
    assert!(
        frames[0].last_mono <= frames[1].first_mono,
        "ordered by time"
    );

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(2), line.join())
        .await
        .expect("the line stops");
}

#[tokio::test]
async fn marks_are_decoded_in_stream_order_and_forgotten_on_reopening() {
    let (first, mut partner) = tokio::io::duplex(64);
    let (second, mut partner2) = tokio::io::duplex(64);
    let opener = Ports(Mutex::new(VecDeque::from([Ok(first), Ok(second)])));
    let (core, engine) = echo_line("marks", "/dev/in-process");
    let shutdown = CancellationToken::new();
    let line = spawn(
        core,
        engine,
        None,
        Arc::new(Nothing),
        opener,
        shutdown.clone(),
    );
    eventually("the port open", || line.status().port_open).await;

    // What the tty layer delivers with INPCK | PARMRK: 01, FF (doubled), 02, 'A' with a
    // parity or framing error, 03, a BREAK, 04; the BREAK's mark split across two reads.
    partner
        .write_all(&[0x01, 0xFF, 0xFF, 0x02, 0xFF, 0x00, b'A', 0x03, 0xFF])
        .await
        .expect("write");
    partner.write_all(&[0x00, 0x00, 0x04]).await.expect("write");
    let expected: &[u8] = b"\x01\xFF\x02<ParityOrFraming>\x03<Break>\x04";
    let mut echo = vec![0u8; expected.len()];
    partner.read_exact(&mut echo).await.expect("echo");
    assert_eq!(echo, expected);
    assert_eq!(
        line.traffic().bytes_received,
        5,
        "data bytes, marks removed"
    );

    // A mark cut off by the port's loss is not completed by the next opening's bytes.
    partner.write_all(&[0x05, 0xFF]).await.expect("write");
    let mut five = [0u8; 1];
    partner.read_exact(&mut five).await.expect("echo");
    assert_eq!(five, [0x05]);
    drop(partner);
    eventually("the port reopened", || {
        line.status().port_opens == 2 && line.status().port_open
    })
    .await;
    partner2.write_all(&[0x00, 0x00]).await.expect("write");
    let mut zeros = [0xAAu8; 2];
    partner2.read_exact(&mut zeros).await.expect("echo");
    assert_eq!(zeros, [0x00, 0x00]);

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(2), line.join())
        .await
        .expect("the line stops");
}

/// What each port of a two-port line handed the engine, in order.
type Got = Arc<Mutex<Vec<(Which, Vec<u8>)>>>;

/// Keeps what each port of a two-port line hands it; never transmits.
struct Listener {
    shared: Arc<Shared>,
    got: Got,
}

impl LineEngine for Listener {
    fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {}

    fn handle_rx(&mut self, _now: proto_core::time::Instant, bytes: &[u8]) {
        let mut got = self.got.lock().unwrap_or_else(PoisonError::into_inner);
        got.push((Which::First, bytes.to_vec()));
    }

    fn handle_line_error(&mut self, _now: proto_core::time::Instant, _error: LineError) {}

    fn handle_timeout(&mut self, _now: proto_core::time::Instant) {}

    fn poll_timeout(&self) -> Option<proto_core::time::Instant> {
        None
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        None
    }

    fn transmitted(&mut self, _at: Instant, _len: usize, _end: proto_core::time::Instant) {}

    fn handle_events(&mut self) -> bool {
        false
    }
}

impl LineCommands for Listener {
    type Command = ();

    fn command(&mut self, (): (), _modem: Option<&mut dyn SerialPort>) {}

    fn refuse(&mut self, (): (), _shutting_down: bool) {}
}

impl LineLifecycle for Listener {
    fn stop(&mut self) -> Stop {
        Stop {
            read: false,
            close_queue: true,
            grace: None,
        }
    }

    fn done(&self) -> bool {
        true
    }

    fn closed(&mut self, _shutting_down: bool) {}

    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.raise(id, None, Some(reason));
    }

    fn monitor_framing(&self) -> Framing {
        Framing {
            kind: proto_core::monitor::FrameKind::Proc3964 { bcc: true },
            gap: Some(Duration::from_millis(50)),
        }
    }
}

impl LineSignals for Listener {}

impl SecondPort for Listener {
    fn handle_rx_second(&mut self, _now: proto_core::time::Instant, bytes: &[u8]) {
        let mut got = self.got.lock().unwrap_or_else(PoisonError::into_inner);
        got.push((Which::Second, bytes.to_vec()));
    }

    fn handle_line_error_second(&mut self, _now: proto_core::time::Instant, error: LineError) {
        let mut got = self.got.lock().unwrap_or_else(PoisonError::into_inner);
        got.push((Which::Second, format!("<{error:?}>").into_bytes()));
    }
}

#[tokio::test]
async fn a_line_with_a_second_port_reads_both_and_records_each_as_its_side() {
    use proto_core::monitor::Direction;
    use proto_core::proc3964::{DLE, STX};

    // First opening: the second port is missing, so neither stays open (02 0Fh names it).
    let (a, mut partner_a) = tokio::io::duplex(64);
    let (b, mut partner_b) = tokio::io::duplex(64);
    let (unused, _unused_partner) = tokio::io::duplex(64);
    let opener = Ports(Mutex::new(VecDeque::from([
        Ok(unused),
        Err("busy".to_owned()),
        Ok(a),
        Ok(b),
    ])));
    let base = LineBase::new(
        "y",
        "listener",
        &PortSettings::new("/dev/in-process-a", 9600),
        8,
        (Duration::from_millis(10), Duration::from_millis(20)),
        None,
    )
    .with_second_port("/dev/in-process-b");
    let core = base.core(Vec::new());
    let got = Arc::new(Mutex::new(Vec::new()));
    let engine = Listener {
        shared: Arc::clone(&core.shared),
        got: Arc::clone(&got),
    };
    let shutdown = CancellationToken::new();
    let line = spawn(
        core,
        engine,
        None,
        Arc::new(Nothing),
        opener,
        shutdown.clone(),
    );
    eventually("the ports open", || line.status().port_open).await;
    assert_eq!(events(&line, EVENT_PORT_SETUP), 1);
    assert_eq!(line.status().port_opens, 1);
    let monitor = Arc::clone(line.monitor().expect("a monitor"));
    assert_eq!(monitor.directions(), [Direction::A, Direction::B]);

    // A asks, B acknowledges, A's telegram begins with a doubled DLE (data 10 20): B's DLE
    // tells A's framing that a telegram follows, so it is one frame, not a DLE and the rest.
    let telegram = [DLE, DLE, 0x20, DLE, 0x03, 0x20 ^ 0x03];
    partner_a.write_all(&[STX]).await.expect("write");
    eventually("A's STX", || monitor.frames_since(0).0.len() == 1).await;
    partner_b.write_all(&[DLE]).await.expect("write");
    eventually("B's DLE", || monitor.frames_since(0).0.len() == 2).await;
    partner_a.write_all(&telegram).await.expect("write");
    eventually("A's telegram", || monitor.frames_since(0).0.len() == 3).await;
    // A parity mark on B's port reaches the engine's second-port hook.
    partner_b
        .write_all(&[0xFF, 0x00, b'x', DLE])
        .await
        .expect("write");
    eventually("B's answer", || monitor.frames_since(0).0.len() == 4).await;
    let (frames, _) = monitor.frames_since(0);
    assert_eq!(
        frames
            .iter()
            .map(|f| (f.direction, f.bytes.clone()))
            .collect::<Vec<_>>(),
        [
            (Direction::A, vec![STX]),
            (Direction::B, vec![DLE]),
            (Direction::A, telegram.to_vec()),
            (Direction::B, vec![DLE]),
        ]
    );
    assert_eq!(
        frames[3].errors.len(),
        1,
        "the parity error inside B's frame"
    );
    let got = got.lock().unwrap_or_else(PoisonError::into_inner).clone();
    let first: Vec<u8> = got
        .iter()
        .filter(|(w, _)| *w == Which::First)
        .flat_map(|(_, b)| b.clone())
        .collect();
    let second: Vec<u8> = got
        .iter()
        .filter(|(w, _)| *w == Which::Second)
        .flat_map(|(_, b)| b.clone())
        .collect();
    assert_eq!(first, [&[STX][..], &telegram].concat());
    assert_eq!(second, b"\x10<ParityOrFraming>\x10");
    assert_eq!(line.traffic().bytes_received, 1 + 6 + 1 + 1);

    // Losing the second port loses the line: 08 0Dh naming it.
    drop(partner_b);
    eventually("the port lost", || events(&line, EVENT_PORT_LOST) == 1).await;
    let error = line.status().port_error.unwrap_or_default();
    assert!(error.contains("/dev/in-process-b"), "{error}");

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(2), line.join())
        .await
        .expect("the line stops");
}

/// An in-process port with UART counters the test sets (`None`: the driver has none).
struct Uart {
    inner: DuplexStream,
    counters: Arc<Mutex<Option<UartCounters>>>,
    asked: Arc<std::sync::atomic::AtomicUsize>,
}

impl AsyncRead for Uart {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl AsyncWrite for Uart {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.inner).poll_write(cx, buf)
    }
    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

impl LinePort for Uart {
    fn uart_counters(&self) -> Option<std::io::Result<UartCounters>> {
        self.asked.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let counters = *self.counters.lock().unwrap_or_else(PoisonError::into_inner);
        Some(counters.ok_or_else(|| std::io::Error::from_raw_os_error(libc::ENOTTY)))
    }
}

struct OneUart(Mutex<Option<Uart>>);

impl PortOpener for OneUart {
    type Port = Uart;

    fn open(&self, _settings: &PortSettings) -> Result<Uart, String> {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take()
            .ok_or_else(|| "no second port".to_owned())
    }
}

#[tokio::test]
async fn a_grown_overrun_count_is_a_line_error_and_a_port_without_counters_is_not_asked_again() {
    let (inner, mut partner) = tokio::io::duplex(64);
    let counters = Arc::new(Mutex::new(Some(UartCounters {
        overrun: 5,
        frame: 2,
        ..UartCounters::default()
    })));
    let asked = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let port = Uart {
        inner,
        counters: Arc::clone(&counters),
        asked: Arc::clone(&asked),
    };
    let (core, engine) = echo_line("uart", "/dev/ttyS0");
    let shutdown = CancellationToken::new();
    let opener = OneUart(Mutex::new(Some(port)));
    let line = spawn(
        core,
        engine,
        None,
        Arc::new(Nothing),
        opener,
        shutdown.clone(),
    );
    eventually("the port open", || line.status().port_open).await;
    let set = |c: Option<UartCounters>| {
        *counters.lock().unwrap_or_else(PoisonError::into_inner) = c;
    };

    // The counts at opening are the start: nothing lost yet.
    partner.write_all(b"a").await.expect("write");
    let mut a = [0u8; 1];
    partner.read_exact(&mut a).await.expect("echo");
    assert_eq!(&a, b"a");

    // Two characters lost (and a framing error, which the marks report, not the counters).
    set(Some(UartCounters {
        overrun: 7,
        frame: 3,
        ..UartCounters::default()
    }));
    partner.write_all(b"b").await.expect("write");
    let expected: &[u8] = b"b<Overrun>";
    let mut got = vec![0u8; expected.len()];
    partner.read_exact(&mut got).await.expect("echo");
    assert_eq!(got, expected);

    // The driver refuses the ioctl: asked once more, then never again on this opening.
    set(None);
    partner.write_all(b"c").await.expect("write");
    let mut c = [0u8; 1];
    partner.read_exact(&mut c).await.expect("echo");
    let after_refusal = asked.load(std::sync::atomic::Ordering::SeqCst);
    partner.write_all(b"d").await.expect("write");
    partner.read_exact(&mut c).await.expect("echo");
    assert_eq!(&c, b"d");
    assert_eq!(
        asked.load(std::sync::atomic::Ordering::SeqCst),
        after_refusal
    );
    assert_eq!(
        after_refusal, 4,
        "at opening and after the reads of a, b and c"
    );

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(2), line.join())
        .await
        .expect("the line stops");
}
