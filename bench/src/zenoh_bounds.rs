//! What a zenoh peer can cost the gateway (`bounds`, real binary, writes over zenoh off):
//! - a flood of `set` puts (2 000 a second): the log lines it leaves, the WARN lines among them,
//!   and how many of the puts `gateway_writes_total` counted as refused;
//! - one put of 8 MiB and one of 256 MiB: how much the gateway's resident memory (VmRSS) grew,
//!   against the put's size.
//!
//! Every put blocks under congestion instead of being dropped by the client, so the gateway
//! receives all of them. A small put after a large one (same priority and reliability, so it
//! arrives after it) tells when the gateway is done with the large one: it is counted as
//! refused (writes are off).

use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use tokio_util::sync::CancellationToken;
use zenoh::qos::CongestionControl;

use crate::child::{free_port, Gateway};
use crate::process::{head, pty, start, zenoh_client};
use crate::report::{Row, Target};

/// The flood's rate.
const FLOOD_RATE: u32 = 2_000;
/// Puts sent back to back in one burst of the flood (the command queue holds 64 by default).
const BURST: u32 = 200;
/// The key of the flood and of the large puts.
const KEY: &str = "gw/bounds/line/dev/value/set";

/// The gateway's HTTP address, from its announcement.
fn http(gw: &Gateway) -> std::io::Result<SocketAddr> {
    gw.output()
        .lines()
        .find_map(|l| l.split("http listening on ").nth(1))
        .and_then(|a| a.trim().parse().ok())
        .ok_or_else(|| std::io::Error::other("the gateway did not announce its HTTP listener"))
}

/// Every `gateway_writes_total` series of refused zenoh writes, added up (with or without a
/// `reason` label, so that a gateway from before it counts too).
fn refused(http: SocketAddr) -> std::io::Result<u64> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(http)?;
    s.write_all(
        format!("GET /metrics HTTP/1.1\r\nHost: {http}\r\nConnection: close\r\n\r\n").as_bytes(),
    )?;
    let mut text = String::new();
    s.read_to_string(&mut text)?;
    Ok(text
        .lines()
        .filter(|l| {
            l.starts_with("gateway_writes_total{")
                && l.contains("path=\"zenoh\"")
                && l.contains("result=\"refused\"")
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<u64>().ok())
        .sum())
}

/// Waits until the refusals reach `n` or `timeout` passed; the last count.
async fn wait_refused(http: SocketAddr, n: u64, timeout: Duration) -> std::io::Result<u64> {
    let deadline = Instant::now() + timeout;
    loop {
        let now = refused(http)?;
        if now >= n || Instant::now() > deadline {
            return Ok(now);
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

async fn put(session: &zenoh::Session, payload: Vec<u8>) -> std::io::Result<()> {
    session
        .put(KEY, payload)
        .congestion_control(CongestionControl::Block)
        .await
        .map_err(|e| std::io::Error::other(e.to_string()))
}

/// A running gateway of these rows.
struct Run {
    gw: Gateway,
    http: SocketAddr,
    session: zenoh::Session,
    /// Keeps the line's pty open.
    _stop: tokio_util::sync::DropGuard,
}

/// A gateway with zenoh on (writes off) and one ASCII line named `line` (so that a command
/// reaches the write check however the gateway orders its checks), its HTTP address and a
/// client session that the gateway has seen put (its subscriber is declared).
async fn gateway(bin: &Path, name: &str) -> std::io::Result<Run> {
    let shutdown = CancellationToken::new();
    let (path, _port) = pty(&shutdown)?;
    let config = format!(
        "{}[lines.line]\nport = \"{path}\"\nprotocol = \"ascii\"\nend_criterion = \"end-chars\"\n\
         end_chars = [0x03]\n",
        head("bounds")
    );
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let gw = start(
        bin,
        name,
        config,
        &["--zenoh-listen".to_owned(), endpoint.clone()],
    )
    .await?;
    let http = http(&gw)?;
    let session = zenoh_client(&endpoint).await?;
    let deadline = Instant::now() + Duration::from_secs(30);
    while refused(http)? == 0 {
        if Instant::now() > deadline {
            return Err(std::io::Error::other("the first put was never counted"));
        }
        put(&session, b"1".to_vec()).await?;
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    Ok(Run {
        gw,
        http,
        session,
        _stop: shutdown.drop_guard(),
    })
}

/// The flood: log lines and WARN lines it left, refusals counted.
pub(crate) async fn flood(bin: &Path, seconds: u32) -> std::io::Result<Vec<Row>> {
    let Run {
        gw,
        http,
        session,
        _stop,
    } = gateway(bin, "zenoh-flood").await?;
    let before = refused(http)?;
    let lines_before = gw.output().lines().count();
    let total = FLOOD_RATE * seconds;
    let begin = tokio::time::Instant::now();
    // Bursts of BURST puts back to back, BURST / FLOOD_RATE seconds apart: the rate of the
    // issue, arriving as a client that sends in batches does.
    let step = Duration::from_secs(1) * BURST / FLOOD_RATE;
    for i in 0..total / BURST {
        tokio::time::sleep_until(begin + step * i).await;
        for _ in 0..BURST {
            put(&session, b"1500".to_vec()).await?;
        }
    }
    let took = begin.elapsed().as_secs_f64();
    let counted =
        wait_refused(http, before + u64::from(total), Duration::from_secs(30)).await? - before;
    let output = gw.output();
    let flood_lines: Vec<&str> = output.lines().skip(lines_before).collect();
    let warn = flood_lines.iter().filter(|l| l.contains("WARN")).count();
    let panicked = gw.panicked();
    let _ = session.close().await;
    drop(gw);
    let conditions = format!(
        "{total} puts of a JSON value on a tag's set key in {took:.1} s, in bursts of {BURST} (writes over zenoh off, \
         RUST_LOG=info), from one client session, blocking under congestion"
    );
    let nan_if = |v: f64| if panicked { f64::NAN } else { v };
    Ok(vec![
        Row {
            name: format!("zenoh flood {FLOOD_RATE}/s x {seconds} s: log lines"),
            measured: format!("{} lines, {warn} WARN", flood_lines.len()),
            reference: "-".into(),
            score: nan_if(flood_lines.len() as f64),
            target: Target::at_most(99.0).with_unit(" lines"),
            note: conditions.clone(),
        },
        Row {
            name: format!("zenoh flood {FLOOD_RATE}/s x {seconds} s: refusals counted"),
            measured: counted.to_string(),
            reference: format!("{total} sent"),
            score: nan_if(counted as f64 / f64::from(total)),
            target: Target::at_least(1.0),
            note: "gateway_writes_total{path=\"zenoh\",result=\"refused\"}, every reason, \
                   30 s allowed after the last put"
                .into(),
        },
    ])
}

/// One put of `mib` MiB: how much VmRSS grew, against the put's size.
pub(crate) async fn large_put(bin: &Path, mib: usize) -> std::io::Result<Row> {
    let Run {
        gw,
        http,
        session,
        _stop,
    } = gateway(bin, &format!("zenoh-put-{mib}")).await?;
    tokio::time::sleep(Duration::from_secs(1)).await;
    let rss = |gw: &Gateway| {
        gw.memory_kib()
            .map(|m| m.rss)
            .ok_or_else(|| std::io::Error::other("no VmRSS"))
    };
    let before = rss(&gw)?;
    let size = mib * 1024 * 1024;
    put(&session, vec![b'7'; size]).await?;
    let counted = refused(http)?;
    put(&session, b"2".to_vec()).await?;
    let after_small = wait_refused(http, counted + 1, Duration::from_secs(120)).await?;
    tokio::time::sleep(Duration::from_secs(1)).await;
    let after = rss(&gw)?;
    let alive = after_small > counted;
    let panicked = gw.panicked();
    let _ = session.close().await;
    drop(gw);
    let grown_mib = after.saturating_sub(before) as f64 / 1024.0;
    Ok(Row {
        name: format!("zenoh {mib} MiB put: VmRSS growth / put size"),
        measured: format!(
            "{:.1} -> {:.1} MiB (+{grown_mib:.1})",
            before as f64 / 1024.0,
            after as f64 / 1024.0
        ),
        reference: format!("{mib} MiB"),
        score: if panicked || !alive {
            f64::NAN
        } else {
            grown_mib / mib as f64
        },
        target: Target::at_most(1.0),
        note: format!(
            "one put of {mib} MiB on a set key (writes off, default [zenoh] max_payload), then \
             a small put whose refusal shows the gateway was done with it and its link is up; \
             VmRSS 1 s before and 1 s after"
        ),
    })
}
