//! `gateway demo`: the embedded config on virtual serial lines with simulated devices.
//!
//! Every line whose port is `pty:<name>` gets a pseudo-terminal pair: the simulated device serves
//! one end in this process, the gateway opens the other end by its path like any serial port.
//! Nothing is needed but the binary.
//!
//! With `--paced`, each line is a paced link instead (two pty pairs joined by a relay that delivers
//! every byte after its character time at the line's baud rate and frame, see
//! [`crate::paced`]), so the virtual line has the timing of a cable: t3.5 gaps, wire time and
//! throughput are those of the real line.

use proto_core::modbus::rtu::CharTiming;
use tokio_serial::{SerialPort, SerialPortBuilderExt, SerialStream};
use tokio_util::sync::CancellationToken;
use tracing::info;

use super::{run_from, AppError, Overrides};
use crate::protocols::{LineConfig, ProtocolConfig, ASCII_CHARACTER_DELAY_RANGE};
use crate::sim::{self, ModbusDevice};

/// The delay-time multiplier of the Modbus lines of `gateway demo --paced` (003 6.4.2.1: 1..10).
const PACED_DELAY_MULTIPLIER: u8 = 10;

/// Runs the demo until `shutdown` is cancelled.
pub async fn demo(overrides: Overrides, shutdown: CancellationToken) -> Result<(), AppError> {
    demo_named(None, overrides, shutdown).await
}

/// [`demo`] under another gateway name than `demo` (its zenoh prefix `gw/<name>`), so that
/// several demos can share one zenoh fabric (deploy/compose.yaml runs two).
pub async fn demo_named(
    name: Option<String>,
    overrides: Overrides,
    shutdown: CancellationToken,
) -> Result<(), AppError> {
    let mut config = crate::plant::demo();
    if let Some(name) = name {
        crate::zenoh_bridge::keys::check_chunk("gateway", &name)
            .map_err(|e| AppError::Setup(format!("--name: {e}")))?;
        config.gateway.name = name;
    }
    // `--token-file`: changes need that token, as on a gateway in a plant.
    if let Some(file) = &overrides.api_token_file {
        config.http.token_file = Some(file.clone());
        config.http.insecure_allow_unauthenticated_changes = false;
    }
    // The gateway's ends of the pty pairs: kept open for the whole run so that the paths stay
    // valid while the gateway reopens them.
    let mut keep = Vec::new();
    // The simulators (and paced relays) stop after the gateway's lines, not with them: a
    // simulated partner that closed its end first would show the gateway's line a lost port
    // (08 0Dh) at every shutdown. The guard stops them however `demo` returns.
    let sims = CancellationToken::new();
    let _stop_sims = sims.clone().drop_guard();
    for (name, line) in &mut config.lines {
        if line.serial.pty_name().is_none() {
            continue;
        }
        if overrides.paced {
            // The relay delivers each byte on a timerfd, on time when a core is free; on a busy
            // machine a byte can still come several milliseconds late, more than t3.5 at 9600 Bd
            // (4 ms): with multiplier 1, a slave line behind a paced link had requests cut in two
            // (CRC errors, no reply) in several of 30 three-second runs on a 2-core machine. The
            // CP's "multiplier character delay time" exists for partners that cannot keep the
            // Modbus timing (003 6.4.2.1, 1..10); the paced demo uses its maximum, so that it
            // shows no errors the machine made.
            // The ASCII line's character delay time (ZVZ, 4 ms at 9600 Bd) gets the same margin:
            // beside three busy processes on two cores it counted 7 events 08 06h a minute.
            match &mut line.protocol {
                ProtocolConfig::ModbusMasterRtu(m) => m.delay_multiplier = PACED_DELAY_MULTIPLIER,
                ProtocolConfig::ModbusSlaveRtu(s) => s.delay_multiplier = PACED_DELAY_MULTIPLIER,
                ProtocolConfig::Ascii(a) => {
                    a.character_delay = a
                        .character_delay
                        .saturating_mul(u32::from(PACED_DELAY_MULTIPLIER))
                        .min(ASCII_CHARACTER_DELAY_RANGE.1);
                }
                _ => {}
            }
        }
        let (device_end, path) = if overrides.paced {
            let settings = crate::paced::PacedSettings {
                baud: line.serial.baud.get(),
                bits_per_char: line.serial.bits_per_char(),
            };
            let (link, _relay) =
                crate::paced::spawn(settings, sims.clone())
                    .await
                    .map_err(|e| {
                        AppError::Setup(format!("line {name}: cannot create a paced link: {e}"))
                    })?;
            let device_end = tokio_serial::new(link.b.as_str(), line.serial.baud.get())
                .open_native_async()
                .map_err(|e| {
                    AppError::Setup(format!("line {name}: cannot open {}: {e}", link.b))
                })?;
            info!(line = %name, port = %link.a, baud = settings.baud, "demo line on a paced link");
            (device_end, link.a)
        } else {
            let (device_end, gateway_end) = SerialStream::pair().map_err(|e| {
                AppError::Setup(format!(
                    "line {name}: cannot create a pseudo-terminal pair: {e}"
                ))
            })?;
            let path = gateway_end.name().ok_or_else(|| {
                AppError::Setup(format!("line {name}: the pseudo-terminal has no path"))
            })?;
            info!(line = %name, port = %path, "demo line on a pseudo-terminal");
            keep.push(gateway_end);
            (device_end, path)
        };
        start_simulator(name, line, device_end, overrides.telegram_every, &sims)?;
        line.serial.port = path;
    }
    // The REST API's start-up line says that changes need no token here (one WARN, the demo's
    // only one, on purpose); the HTTP server's start says that changes are kept in memory.
    let result = run_from(config, Some(crate::plant::demo_toml()), overrides, shutdown).await;
    sims.cancel();
    drop(keep);
    result
}

/// How often the demo's consumer looks at the mailboxes: well within the time the demo's partners
/// (one telegram a second each, plus the echoes) need to fill half of a mailbox.
const CONSUME_EVERY: std::time::Duration = std::time::Duration::from_millis(500);

/// The demo's own consumer of its telegram lines: keeps every mailbox at most half full by
/// acknowledging its oldest telegrams, so that the demo runs without 08 0Ah (no free receive
/// buffer, 003 7.2) while clients still read recent telegrams and acknowledge them themselves.
/// Follows configuration changes: the lines are looked up at every round.
pub(super) async fn consume_mailboxes(
    sup: std::sync::Arc<super::supervisor::Supervisor>,
    shutdown: CancellationToken,
) {
    let mut tick = tokio::time::interval(CONSUME_EVERY);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            () = shutdown.cancelled() => return,
            _ = tick.tick() => {}
        }
        let snapshot = sup.snapshot();
        for line in snapshot.lines.values() {
            if let Some(mailbox) = line.handle.mailbox() {
                keep_half(&mailbox);
            }
        }
    }
}

/// Acknowledges the oldest telegrams of `mailbox` until at most half of its depth waits; how
/// many it acknowledged.
fn keep_half(mailbox: &crate::mailbox::Mailbox) -> usize {
    let keep = mailbox.settings().queue_depth / 2;
    let mut acknowledged = 0;
    while mailbox.len() > keep {
        let Some(head) = mailbox.head() else {
            break;
        };
        // A client acknowledged it meanwhile: the next round sees the new head.
        if mailbox.ack(head.seq).is_err() {
            break;
        }
        acknowledged += 1;
    }
    acknowledged
}

/// Starts the simulated device of a demo line on `stream`.
fn start_simulator(
    name: &str,
    line: &LineConfig,
    stream: SerialStream,
    telegram_every: Option<std::time::Duration>,
    shutdown: &CancellationToken,
) -> Result<(), AppError> {
    let timing = CharTiming::new(line.serial.baud.get(), line.serial.bits_per_char());
    let timing = match &line.protocol {
        ProtocolConfig::ModbusMasterRtu(m) => timing.with_multiplier(m.delay_multiplier),
        _ => timing,
    };
    match &line.protocol {
        ProtocolConfig::ModbusMasterRtu(m) => {
            // Every device of the line on one simulated bus (multi-drop): each answers its own
            // slave address.
            let mut devices: Vec<Box<dyn ModbusDevice>> = Vec::new();
            // The demo's generic device is the meter of every tag type; a profile without a
            // simulator has no device on the bus (the line reports it offline).
            for device in m.devices.values() {
                match sim::model_for_profile(device.profile.name()) {
                    Some(model) => devices.push((model.build)(device.address, Default::default())),
                    None => tracing::warn!(
                        profile = device.profile.name(),
                        "no simulator plays this profile; the demo line has no such device"
                    ),
                }
            }
            if devices.is_empty() {
                return Ok(());
            }
            let sim: Box<dyn ModbusDevice> = if devices.len() == 1 {
                devices.remove(0)
            } else {
                Box::new(sim::bus::Bus::new(devices))
            };
            let token = shutdown.clone();
            let line_name = name.to_owned();
            crate::task::spawn("demo simulated device", async move {
                if let Err(e) = sim::serve_modbus(stream, sim, timing, token).await {
                    tracing::error!(line = %line_name, error = %e, "simulated device stopped");
                }
            });
            Ok(())
        }
        ProtocolConfig::ModbusSlaveRtu(cfg) => {
            // A simulated HMI polls the gateway's slave line and writes a cycle counter into
            // holding register 10 (DB 800, DBW 20), so that values and counters move.
            let layout = crate::protocols::modbus_slave::cpmem::memory_layout([cfg], None);
            let params = crate::protocols::modbus_slave::cpmem::slave_params(cfg, &layout)
                .map_err(|issues| {
                    let text: Vec<String> = issues.iter().map(ToString::to_string).collect();
                    AppError::Setup(format!("line {name}: {}", text.join("; ")))
                })?;
            let mut settings =
                crate::protocols::modbus_slave::partner::SimMasterSettings::for_slave(
                    &params,
                    Some(10),
                );
            settings.baud = line.serial.baud.get();
            settings.bits_per_char = line.serial.bits_per_char();
            crate::protocols::modbus_slave::partner::spawn_sim_master(
                stream,
                settings,
                shutdown.clone(),
            );
            Ok(())
        }
        ProtocolConfig::Proc3964(_) | ProtocolConfig::Ascii(_) => {
            // The partner echoes every telegram and sends one of its own every second (the
            // 3964R partner at the other priority, the ASCII partner ending with ETX).
            let partner = crate::protocols::telegram::partner::TelegramSim::for_line(line)
                .ok_or_else(|| AppError::Setup(format!("line {name}: no telegram partner")))?
                .map_err(|e| AppError::Setup(format!("line {name}: {e}")))?;
            let partner = match telegram_every {
                Some(every) => partner.every(every),
                None => partner,
            };
            crate::task::spawn(
                "demo telegram partner",
                partner.serve(stream, shutdown.clone()),
            );
            Ok(())
        }
        _ => {
            // The demo has no Modbus ASCII or tap line; a config that adds one (or a line of a
            // protocol without a simulated partner) gets no simulator.
            drop(stream);
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::SystemTime;

    use super::keep_half;
    use crate::mailbox::{Delivery, Mailbox, MailboxSettings, Overflow};

    #[test]
    fn the_demo_consumer_keeps_a_mailbox_half_full_and_it_never_overflows() {
        let mailbox = Mailbox::new(
            "r3964",
            MailboxSettings {
                queue_depth: 8,
                overflow: Overflow::Refuse,
                ..MailboxSettings::default()
            },
            250,
        );
        for round in 0..100u32 {
            for _ in 0..3 {
                let delivery = mailbox.deliver(round.to_be_bytes().to_vec(), SystemTime::now());
                assert!(
                    matches!(delivery, Delivery::Kept { .. }),
                    "round {round}: {delivery:?}"
                );
            }
            keep_half(&mailbox);
            assert_eq!(mailbox.len(), if round == 0 { 3 } else { 4 });
        }
        // The newest stay for the clients, oldest first.
        let waiting: Vec<u16> = mailbox.waiting().iter().map(|t| t.seq).collect();
        assert_eq!(waiting, vec![297, 298, 299, 300]);
        assert_eq!(keep_half(&mailbox), 0);
    }
}
