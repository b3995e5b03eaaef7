//! What the mailbox journal costs a 3964R line: telegrams per second received over a paced link
//! at 9600 Bd, with and without `journal`, and the largest size the journal reached against its
//! stated bound.
//!
//! ```text
//!  telegram line (gateway) ═ pty ═ paced link 9600 8E1 ═ pty ═ 3964R partner (gateway sim)
//!        │ mailbox ──> a consumer that acknowledges every telegram at once
//!        └─ journal (a file under the system's temp directory), or none
//! ```
//!
//! The partner keeps its send queue full, so the line carries back-to-back telegrams: the rate
//! is what the procedure allows at 9600 Bd (STX, DLE, 12 user bytes, DLE ETX BCC, DLE: 18
//! characters of 11 bits, 20.6 ms) plus the turnarounds, and with a journal one synced write
//! per telegram before the final DLE. The two runs alternate so that a slow second on the shared
//! machine hits both.

use std::sync::Arc;
use std::time::{Duration, Instant};

use gateway::mailbox::journal::size_bound;
use gateway::mailbox::Mailbox;
use gateway::paced::{self, PacedSettings};
use gateway::protocols::telegram::partner::{partner_3964r, TelegramSim};
use gateway::protocols::telegram::{spawn_telegram_line, TelegramLineSettings, TelegramProtocol};
use gateway::serial::PortSettings;
use proto_core::proc3964::{Params3964, Settings3964};
use tokio_util::sync::CancellationToken;

use crate::report::{Row, Target};
use crate::Plan;

const BAUD: u32 = 9600;

/// One run: telegrams per second received (and acknowledged), and the journal's largest size.
struct Run {
    rate: f64,
    received: u64,
    journal_max: Option<u64>,
}

/// The rows: the journaled rate against the unjournaled one, and the journal's size against its
/// bound.
pub(crate) async fn journal_cost(plan: &Plan) -> std::io::Result<Vec<Row>> {
    let dir = std::env::temp_dir().join(format!("gateway-bench-journal-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (mut with, mut without) = (Vec::new(), Vec::new());
    // One journal for every round: each round restarts the line on it (restored, then appended
    // to), so a full run appends enough to compact it several times.
    let journal = dir.join("r3964.journal");
    for _ in 0..plan.journal_rounds {
        with.push(run(Some(journal.clone()), plan.journal_window).await?);
        without.push(run(None, plan.journal_window).await?);
    }
    let _ = std::fs::remove_dir_all(&dir);
    let mean = |runs: &[Run]| runs.iter().map(|r| r.rate).sum::<f64>() / runs.len().max(1) as f64;
    let (rate_with, rate_without) = (mean(&with), mean(&without));
    let largest = with.iter().filter_map(|r| r.journal_max).max().unwrap_or(0);
    let bound = size_bound(
        gateway::mailbox::DEFAULT_QUEUE_DEPTH as u64,
        u64::from(proto_core::proc3964::DEFAULT_MAX_LEN),
    );
    Ok(vec![
        Row {
            name: "3964R telegrams/s at 9600 Bd, journal / none".into(),
            measured: format!("{rate_with:.1}/s"),
            reference: format!("{rate_without:.1}/s"),
            score: rate_with / rate_without,
            // Our target: the journal may take at most a fifth of a 9600 Bd line's rate.
            target: Target::at_least(0.8),
            note: format!(
                "paced link, back-to-back 12-byte telegrams, each acknowledged at once; one \
                 write + fdatasync per telegram on {} before the final DLE: {:.1} ms a telegram; \
                 {} rounds of {:?}",
                std::env::temp_dir().display(),
                1000.0 / rate_with - 1000.0 / rate_without,
                plan.journal_rounds,
                plan.journal_window
            ),
        },
        Row {
            name: "journal size, largest / bound".into(),
            measured: format!("{largest} B"),
            reference: format!("{bound} B"),
            score: largest as f64 / bound as f64,
            target: Target::at_most(1.0),
            note: format!(
                "bound = 2 x (250 telegrams of 250 bytes as records) + 64 KiB + one record \
                 (docs/mailbox.md); {} telegrams through one journal over the rounds (each round \
                 restarts the line on it, which compacts it; a round of 1,500 telegrams or more \
                 compacts it while running, about every 64 KiB)",
                with.iter().map(|r| r.received).sum::<u64>()
            ),
        },
    ])
}

async fn run(journal: Option<std::path::PathBuf>, window: Duration) -> std::io::Result<Run> {
    let shutdown = CancellationToken::new();
    let link_settings = PacedSettings::from_frame(BAUD, 8, true, 1);
    let char_time = link_settings.char_time();
    let (link, _relay) = paced::spawn(link_settings, shutdown.clone()).await?;

    let params = Params3964::try_new(Settings3964 {
        baud: BAUD,
        ..Settings3964::default()
    })
    .map_err(|e| std::io::Error::other(e.to_string()))?;
    let mut settings = TelegramLineSettings::new(
        "r3964",
        PortSettings::new(&link.a, BAUD),
        TelegramProtocol::P3964(params),
    );
    settings.journal = journal;
    let line = spawn_telegram_line(settings, shutdown.clone());
    let mailbox = line
        .mailbox()
        .ok_or_else(|| std::io::Error::other("no mailbox"))?;
    tokio::spawn(consume(Arc::clone(&mailbox), shutdown.clone()));

    let partner = partner_3964r(BAUD).map_err(|e| std::io::Error::other(e.to_string()))?;
    let port = tokio_serial::SerialStream::open(&tokio_serial::new(&link.b, BAUD))
        .map_err(std::io::Error::from)?;
    let sim = TelegramSim::new(TelegramProtocol::P3964(partner))
        .every(Duration::from_millis(1))
        .echo(false)
        .char_time(char_time);
    tokio::spawn(sim.serve(port, shutdown.clone()));

    // Warm up: the port opens and the first telegrams pass.
    let warm = Instant::now() + Duration::from_secs(5);
    while mailbox.counters().received < 5 && Instant::now() < warm {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let (start, from) = (Instant::now(), mailbox.counters().received);
    let mut journal_max = mailbox.journal_size();
    while start.elapsed() < window {
        tokio::time::sleep(Duration::from_millis(20)).await;
        journal_max = journal_max.max(mailbox.journal_size());
    }
    let received = mailbox.counters().received - from;
    let rate = received as f64 / start.elapsed().as_secs_f64();
    shutdown.cancel();
    line.join().await;
    Ok(Run {
        rate,
        received,
        journal_max,
    })
}

/// Acknowledges every telegram as it arrives.
async fn consume(mailbox: Arc<Mailbox>, shutdown: CancellationToken) {
    let mut rx = mailbox.subscribe();
    loop {
        tokio::select! {
            () = shutdown.cancelled() => return,
            _ = rx.recv() => {}
        }
        while let Some(t) = mailbox.head() {
            let _ = mailbox.ack(t.seq);
        }
    }
}
