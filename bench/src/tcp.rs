//! Modbus TCP rows: cached FC 03 reads of the gateway against a bare tokio-modbus server serving
//! a flat image, and the latency a write through the gateway adds to the serial exchange.
//!
//! Both servers run on the bench's multi-threaded runtime (two workers, as the gateway binary on
//! this machine); the clients run on a runtime of their own on a separate thread and are the same
//! raw MBAP loop for both. The servers take turns (bare, gateway, gateway, bare, ...) so that a
//! change of the machine's load hits both.

use std::fmt::Write as _;
use std::net::SocketAddr;
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

use gateway::app::MetricsRegistry;
use gateway::image::{ImageConfig, ProcessImage};
use gateway::line::LineHandle;
use gateway::modbus_tcp::{self, ServerOptions, ServerStats, TlsServer};
use gateway::protocols::{spawn_modbus_master_line, DeviceSettings, LineSettings};
use gateway::serial::PortSettings;
use gateway::sim::serve_modbus;
use gateway::unit::UnitMap;
use proto_core::modbus::rtu::CharTiming;
use tokio_rustls::TlsConnector;
use tokio_serial::SerialStream;
use tokio_util::sync::CancellationToken;

use crate::device::FlatDevice;
use crate::mbap::Client;
use crate::poll::{polled, rig};
use crate::report::{Row, Target};
use crate::stats::{mean, ms, percentile, tail};
use crate::tap::lock;
use crate::Plan;

/// The unit id of the benchmark's device.
const UNIT: u8 = 1;

/// Serves `line`'s devices over Modbus TCP on an ephemeral loopback port until `shutdown`.
pub(crate) async fn serve_gateway(
    line: &LineHandle,
    shutdown: CancellationToken,
) -> std::io::Result<SocketAddr> {
    serve_gateway_over(line, None, shutdown).await
}

/// [`serve_gateway`], over Modbus/TCP Security with `tls`, or plain without.
async fn serve_gateway_over(
    line: &LineHandle,
    tls: Option<TlsServer>,
    shutdown: CancellationToken,
) -> std::io::Result<SocketAddr> {
    let mut units = UnitMap::new();
    for (id, unit) in line.device_units() {
        units.insert(id, Arc::new(unit));
    }
    // As the gateway's unit map: forwarded unit ids only where no device holds them.
    for (id, unit) in line.transparent_units() {
        if units.get(id).is_none() {
            units.insert(id, unit);
        }
    }
    let listener = modbus_tcp::bind(SocketAddr::from(([127, 0, 0, 1], 0)))?;
    let addr = listener.local_addr()?;
    let options = ServerOptions {
        max_connections: 64,
        ..ServerOptions::default()
    };
    // Counted into the Prometheus families as in the gateway binary, which always registers them.
    let metrics = MetricsRegistry::new().map_err(std::io::Error::other)?;
    let units = Arc::new(RwLock::new(units));
    let stats = Arc::new(ServerStats::with_metrics(
        metrics.metrics.modbus_tcp().clone(),
        metrics.metrics.audit().clone(),
    ));
    match tls {
        None => {
            tokio::spawn(modbus_tcp::serve(listener, units, options, shutdown, stats));
        }
        Some(tls) => {
            tokio::spawn(modbus_tcp::serve_tls(
                listener, units, options, tls, shutdown, stats,
            ));
        }
    }
    Ok(addr)
}

/// The gateway with a device polled (125 registers every 100 ms) on a plain pty pair, so that the
/// image stays fresh, served over Modbus TCP.
async fn cached_gateway(shutdown: &CancellationToken) -> std::io::Result<SocketAddr> {
    let line = cached_line(shutdown)?;
    serve_gateway(&line, shutdown.clone()).await
}

/// The line of [`cached_gateway`]: a device polled (125 registers every 100 ms) on a pty pair.
fn cached_line(shutdown: &CancellationToken) -> std::io::Result<LineHandle> {
    const BAUD: u32 = 115_200;
    let (device_end, line_end) = SerialStream::pair().map_err(std::io::Error::from)?;
    let path = tokio_serial::SerialPort::name(&line_end)
        .ok_or_else(|| std::io::Error::other("the pty has no path"))?;
    let stop = shutdown.clone();
    tokio::spawn(async move {
        // Keeps the line's end open until the end, so the device's end never hangs up.
        let _keep = line_end;
        stop.cancelled().await;
    });
    tokio::spawn(serve_modbus(
        device_end,
        FlatDevice::new(UNIT),
        CharTiming::new(BAUD, 11),
        shutdown.clone(),
    ));
    let line = spawn_modbus_master_line(
        LineSettings::rtu("tcp", PortSettings::new(path, BAUD)),
        vec![polled("d1", UNIT, 125, Duration::from_millis(100))],
        // Fresh for 20 poll periods (2 s) instead of the default 3: on a busy machine the line and
        // the simulated device, which share the runtime with both servers and the clients' load,
        // can miss polls for longer than 300 ms, and the gateway then rightly answers 0x0B. The
        // staleness check itself runs on every read either way.
        ProcessImage::new(ImageConfig {
            stale_factor: 20,
            ..ImageConfig::default()
        }),
        shutdown.clone(),
    );
    Ok(line)
}

/// A tokio-modbus server answering FC 03 from a flat image of 65536 registers.
#[derive(Clone)]
struct FlatService(Arc<Vec<u16>>);

impl tokio_modbus::server::Service for FlatService {
    type Request = tokio_modbus::Request<'static>;
    type Response = tokio_modbus::Response;
    type Exception = tokio_modbus::ExceptionCode;
    type Future = std::future::Ready<Result<Self::Response, Self::Exception>>;

    fn call(&self, request: Self::Request) -> Self::Future {
        std::future::ready(match request {
            tokio_modbus::Request::ReadHoldingRegisters(address, count) => {
                let start = usize::from(address);
                self.0
                    .get(start..start + usize::from(count))
                    .map(|v| tokio_modbus::Response::ReadHoldingRegisters(v.to_vec()))
                    .ok_or(tokio_modbus::ExceptionCode::IllegalDataAddress)
            }
            _ => Err(tokio_modbus::ExceptionCode::IllegalFunction),
        })
    }
}

/// The bare reference server on an ephemeral loopback port, until `shutdown`.
async fn bare_server(shutdown: &CancellationToken) -> std::io::Result<SocketAddr> {
    let listener = tokio::net::TcpListener::bind(SocketAddr::from(([127, 0, 0, 1], 0))).await?;
    let addr = listener.local_addr()?;
    let image = Arc::new((0..=u16::MAX).collect::<Vec<u16>>());
    let server = tokio_modbus::server::tcp::Server::new(listener);
    let stop = shutdown.clone();
    tokio::spawn(async move {
        let on_connected = |stream: tokio::net::TcpStream, peer| {
            let service = FlatService(Arc::clone(&image));
            // As the gateway's server does: an answer written behind another that is not yet
            // acknowledged goes out at once (without it, Nagle and the client's delayed ACK hold
            // each second answer of a pipelined burst for 40 ms).
            let _ = stream.set_nodelay(true);
            async move {
                tokio_modbus::server::tcp::accept_tcp_connection(stream, peer, |_| {
                    Ok(Some(service.clone()))
                })
            }
        };
        tokio::select! {
            _ = server.serve(&on_connected, |_err| {}) => {}
            () = stop.cancelled() => {}
        }
    });
    Ok(addr)
}

/// What a load run measured.
#[derive(Default)]
struct Load {
    requests: u64,
    elapsed: Duration,
    latencies: Vec<Duration>,
    /// CPU time of the bench runtime's worker threads (the servers, and the line polling the
    /// gateway's device) during the run.
    server_cpu: Duration,
}

/// Clock ticks a second in `/proc/<pid>/task/<tid>/stat` (`USER_HZ`, 100 on Linux).
const USER_HZ: u64 = 100;

/// CPU time (user and system) used so far by the worker threads of the bench's runtime, where
/// both servers run: the sum over `/proc/self/task/*/stat` of the threads named like tokio's
/// workers. Zero where `/proc` is missing.
fn worker_cpu() -> Duration {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return Duration::ZERO;
    };
    let ticks: u64 = tasks
        .flatten()
        .filter(|task| {
            std::fs::read_to_string(task.path().join("comm"))
                .is_ok_and(|comm| comm.starts_with("tokio-r"))
        })
        .filter_map(|task| {
            let stat = std::fs::read_to_string(task.path().join("stat")).ok()?;
            // After "pid (comm)": state is field 3, utime field 14, stime field 15.
            let (_, rest) = stat.rsplit_once(')')?;
            let fields: Vec<&str> = rest.split_whitespace().collect();
            let utime: u64 = fields.get(11)?.parse().ok()?;
            let stime: u64 = fields.get(12)?.parse().ok()?;
            Some(utime + stime)
        })
        .sum();
    Duration::from_millis(ticks * 1000 / USER_HZ)
}

/// `connections` clients reading 125 registers as fast as answers come, `depth` requests written
/// at once (1: one at a time), for `duration`, on a runtime of their own on a separate thread.
async fn load(
    addr: SocketAddr,
    connections: usize,
    depth: usize,
    duration: Duration,
) -> std::io::Result<Load> {
    load_over(addr, None, connections, depth, duration).await
}

/// [`load`] over TLS with `tls`'s client certificate, or plain without.
async fn load_over(
    addr: SocketAddr,
    tls: Option<TlsConnector>,
    connections: usize,
    depth: usize,
    duration: Duration,
) -> std::io::Result<Load> {
    let (tx, rx) = tokio::sync::oneshot::channel();
    std::thread::spawn(move || {
        let result = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .and_then(|rt| {
                rt.block_on(load_on_this_thread(
                    addr,
                    tls.as_ref(),
                    connections,
                    depth,
                    duration,
                ))
            });
        let _ = tx.send(result);
    });
    rx.await
        .map_err(|_| std::io::Error::other("the load thread stopped"))?
}

async fn load_on_this_thread(
    addr: SocketAddr,
    tls: Option<&TlsConnector>,
    connections: usize,
    depth: usize,
    duration: Duration,
) -> std::io::Result<Load> {
    let mut clients = Vec::with_capacity(connections);
    for _ in 0..connections {
        let mut client = Client::connect_to(addr, tls).await?;
        client.read_125(UNIT).await?;
        clients.push(client);
    }
    let cpu_before = worker_cpu();
    let start = Instant::now();
    let until = start + duration;
    let tasks: Vec<_> = clients
        .into_iter()
        .map(|mut client| {
            tokio::spawn(async move {
                let mut latencies = Vec::with_capacity(65_536);
                while Instant::now() < until {
                    let t = Instant::now();
                    if depth > 1 {
                        client.read_125_pipelined(UNIT, depth).await?;
                    } else {
                        client.read_125(UNIT).await?;
                    }
                    latencies.push(t.elapsed());
                }
                Ok::<_, std::io::Error>(latencies)
            })
        })
        .collect();
    let mut out = Load::default();
    for task in tasks {
        let latencies = task.await.map_err(std::io::Error::other)??;
        out.requests += (latencies.len() * depth) as u64;
        out.latencies.extend(latencies);
    }
    out.elapsed = start.elapsed();
    out.server_cpu = worker_cpu().saturating_sub(cpu_before);
    Ok(out)
}

/// Waits until `addr` answers a read of 125 registers from unit 1 (the image is filled).
async fn until_answers(addr: SocketAddr) -> std::io::Result<()> {
    until_answers_over(addr, None).await
}

/// [`until_answers`] over TLS with `tls`, or plain without.
async fn until_answers_over(addr: SocketAddr, tls: Option<&TlsConnector>) -> std::io::Result<()> {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let result = async { Client::connect_to(addr, tls).await?.read_125(UNIT).await }.await;
        match result {
            Ok(()) => return Ok(()),
            Err(e) if Instant::now() > deadline => return Err(e),
            Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    }
}

/// Requests a pipelining client of the cached rows writes at once.
const PIPELINED: usize = 8;

/// Throughput and p99 rows for 1 and 16 connections, and for 1 connection writing
/// [`PIPELINED`] requests at once (p99 of the whole burst). Target: 1.2 x the bare server's
/// requests/s, p99 no worse than its.
pub(crate) async fn cached_reads(plan: &Plan) -> std::io::Result<Vec<Row>> {
    let shutdown = CancellationToken::new();
    let _stop = shutdown.clone().drop_guard();
    let gateway = cached_gateway(&shutdown).await?;
    let bare = bare_server(&shutdown).await?;
    until_answers(gateway).await?;
    until_answers(bare).await?;
    let mut rows = Vec::new();
    for (connections, depth) in [(1usize, 1usize), (16, 1), (1, PIPELINED)] {
        let (mut gw, mut reference) = (Load::default(), Load::default());
        for round in 0..plan.tcp_rounds {
            let order = if round % 2 == 0 {
                [(bare, false), (gateway, true)]
            } else {
                [(gateway, true), (bare, false)]
            };
            for (addr, is_gateway) in order {
                let run = load(addr, connections, depth, plan.tcp_slice).await?;
                let into = if is_gateway { &mut gw } else { &mut reference };
                into.requests += run.requests;
                into.elapsed += run.elapsed;
                into.latencies.extend(run.latencies);
                into.server_cpu += run.server_cpu;
            }
        }
        let rate = |l: &Load| l.requests as f64 / l.elapsed.as_secs_f64().max(1e-9);
        let (gw_rate, bare_rate) = (rate(&gw), rate(&reference));
        let (gw_p50, gw_p99) = (
            percentile(&gw.latencies, 50.0),
            percentile(&gw.latencies, 99.0),
        );
        let (bare_p50, bare_p99) = (
            percentile(&reference.latencies, 50.0),
            percentile(&reference.latencies, 99.0),
        );
        let cpu = |l: &Load| l.server_cpu.as_secs_f64() * 1e6 / (l.requests as f64).max(1.0);
        let conditions = format!(
            "{} rounds of {:.2} s each, servers alternating; p50 gateway {} / bare {} = {:.2}; \
             server threads' CPU per request gateway {:.1} us / bare {:.1} us = {:.2}",
            plan.tcp_rounds,
            plan.tcp_slice.as_secs_f64(),
            ms(gw_p50),
            ms(bare_p50),
            gw_p50.as_secs_f64() / bare_p50.as_secs_f64().max(1e-12),
            cpu(&gw),
            cpu(&reference),
            cpu(&gw) / cpu(&reference).max(1e-12),
        );
        let shape = match depth {
            1 => format!("{connections} conn"),
            _ => format!("{connections} conn x {depth} pipelined"),
        };
        rows.push(Row {
            name: format!("TCP FC03 x125 cached, {shape}: requests/s / bare"),
            measured: format!("{gw_rate:.0}/s"),
            reference: format!("{bare_rate:.0}/s"),
            score: gw_rate / bare_rate,
            target: Target::at_least(1.2),
            note: conditions,
        });
        rows.push(Row {
            name: format!("TCP FC03 x125 cached, {shape}: p99 / bare p99"),
            measured: ms(gw_p99),
            reference: ms(bare_p99),
            score: gw_p99.as_secs_f64() / bare_p99.as_secs_f64().max(1e-12),
            target: Target::at_most(1.0),
            note: String::new(),
        });
    }
    Ok(rows)
}

/// Throughput and p99 rows for 1 and 16 connections of the gateway over Modbus/TCP Security
/// against the same gateway (one line, one image) over plain Modbus TCP: the cost of TLS.
/// Connections are opened (handshake included) before each timed slice, so the rows measure the
/// record layer of a kept connection, as a SCADA client uses it.
pub(crate) async fn cached_reads_tls(plan: &Plan) -> std::io::Result<Vec<Row>> {
    let shutdown = CancellationToken::new();
    let _stop = shutdown.clone().drop_guard();
    let tls = crate::tls::make()?;
    let line = cached_line(&shutdown)?;
    let plain = serve_gateway(&line, shutdown.clone()).await?;
    let secure = serve_gateway_over(&line, Some(tls.server.clone()), shutdown.clone()).await?;
    until_answers(plain).await?;
    until_answers_over(secure, Some(&tls.connector)).await?;
    let mut rows = Vec::new();
    for connections in [1usize, 16] {
        let (mut over_tls, mut over_tcp) = (Load::default(), Load::default());
        for round in 0..plan.tcp_rounds {
            let order = if round % 2 == 0 {
                [false, true]
            } else {
                [true, false]
            };
            for is_tls in order {
                let run = if is_tls {
                    load_over(
                        secure,
                        Some(tls.connector.clone()),
                        connections,
                        1,
                        plan.tcp_slice,
                    )
                    .await?
                } else {
                    load(plain, connections, 1, plan.tcp_slice).await?
                };
                let into = if is_tls { &mut over_tls } else { &mut over_tcp };
                into.requests += run.requests;
                into.elapsed += run.elapsed;
                into.latencies.extend(run.latencies);
                into.server_cpu += run.server_cpu;
            }
        }
        let rate = |l: &Load| l.requests as f64 / l.elapsed.as_secs_f64().max(1e-9);
        let (tls_rate, tcp_rate) = (rate(&over_tls), rate(&over_tcp));
        let p = |l: &Load, q| percentile(&l.latencies, q);
        let cpu = |l: &Load| l.server_cpu.as_secs_f64() * 1e6 / (l.requests as f64).max(1.0);
        let conditions = format!(
            "TLS 1.3 (ring, client certificate with a role), {} rounds of {:.2} s each, \
             alternating; p50 TLS {} / plain {} = {:.2}; server threads' CPU per request TLS \
             {:.1} us / plain {:.1} us = {:.2}",
            plan.tcp_rounds,
            plan.tcp_slice.as_secs_f64(),
            ms(p(&over_tls, 50.0)),
            ms(p(&over_tcp, 50.0)),
            p(&over_tls, 50.0).as_secs_f64() / p(&over_tcp, 50.0).as_secs_f64().max(1e-12),
            cpu(&over_tls),
            cpu(&over_tcp),
            cpu(&over_tls) / cpu(&over_tcp).max(1e-12),
        );
        rows.push(Row {
            name: format!("TLS FC03 x125 cached, {connections} conn: requests/s / plain TCP"),
            measured: format!("{tls_rate:.0}/s"),
            reference: format!("{tcp_rate:.0}/s"),
            score: tls_rate / tcp_rate,
            // TLS may cost up to half the plain throughput of cached reads.
            target: Target::at_least(0.5),
            note: conditions,
        });
        rows.push(Row {
            name: format!("TLS FC03 x125 cached, {connections} conn: p99 / plain TCP p99"),
            measured: ms(p(&over_tls, 99.0)),
            reference: ms(p(&over_tcp, 99.0)),
            score: p(&over_tls, 99.0).as_secs_f64() / p(&over_tcp, 99.0).as_secs_f64().max(1e-12),
            target: Target::at_most(2.0),
            note: String::new(),
        });
    }
    Ok(rows)
}

/// A write (FC 06) through Modbus TCP to a device on a paced 19200 Bd line: the client's latency
/// minus the time the exchange spent on the serial side: the request written by the master to the
/// answer back at the master (measured by the tap), and the t3.5 of silence after the answer's
/// last byte, which a conformant master waits before it takes the answer as ended (003 6.4.3: the
/// frame ends by silence; Modbus over Serial Line V1.02, 2.5.1.1).
pub(crate) async fn write_latency(plan: &Plan) -> std::io::Result<Vec<Row>> {
    const BAUD: u32 = 19_200;
    let rig = rig(
        BAUD,
        FlatDevice::new(UNIT),
        vec![DeviceSettings::new("d1", UNIT, UNIT)],
        None,
    )
    .await?;
    let shutdown = CancellationToken::new();
    let _stop = shutdown.clone().drop_guard();
    let addr = serve_gateway(&rig.line, shutdown).await?;
    let mut client = Client::connect(addr).await?;
    client.write_one(UNIT, 100, 0).await?;
    let mut overheads = Vec::with_capacity(plan.writes);
    let mut serial_times = Vec::with_capacity(plan.writes);
    for i in 0..plan.writes {
        // The line is idle and its t3.5 gap over before each write.
        tokio::time::sleep(Duration::from_millis(5)).await;
        let before = lock(&rig.master.log).exchanges.len();
        let t = Instant::now();
        client.write_one(UNIT, 100, i as u16).await?;
        let latency = t.elapsed();
        tokio::time::sleep(Duration::from_millis(1)).await;
        let exchange = lock(&rig.master.log).exchanges.get(before).copied();
        // The master ends the answer t3.5 after its last byte: serial time, not the gateway's.
        let end_of_answer = rig.master_timing.t3_5();
        let Some(serial) = exchange.and_then(|e| e.answered.map(|a| a - e.sent + end_of_answer))
        else {
            return Err(std::io::Error::other(
                "the tap did not see the write's exchange",
            ));
        };
        serial_times.push(serial);
        overheads.push(latency.saturating_sub(serial));
    }
    let wire = rig.timing.char_time * 16;
    let turnaround = mean(&lock(&rig.device).turnarounds);
    let mut note = format!(
        "{} writes of one register at {BAUD} Bd 8E1, one at a time; {}; serial side mean {} \
         (wire {} + device {} + link lateness + the master's t3.5 after the answer {}, which \
         ends the answer by silence)",
        plan.writes,
        tail(&overheads),
        ms(mean(&serial_times)),
        ms(wire),
        ms(turnaround),
        ms(rig.master_timing.t3_5()),
    );
    // The in-process gateway's tasks, in a bench built with gateway/stall-watch.
    let stalls = gateway::task::stalls();
    if let Some(count) = stalls.lines().next() {
        eprintln!("  stalls of the bench's gateway tasks so far:\n{stalls}");
        let _ = write!(note, "; {count} in the bench's gateway tasks so far");
    }
    let row = |what: &str, p: f64, limit: f64, note: String| {
        let value = percentile(&overheads, p);
        Row {
            name: format!("TCP write to a device: latency - serial time (t3.5 incl.), {what}"),
            measured: ms(value),
            reference: "-".into(),
            score: value.as_secs_f64() * 1e3,
            target: Target::at_most(limit).with_unit(" ms"),
            note,
        }
    };
    Ok(vec![
        row("p99", 99.0, 1.0, note),
        row("max", 100.0, 2.0, String::new()),
    ])
}
