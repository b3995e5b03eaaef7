//! A simulated serial Modbus master for the demo: it polls the gateway's Modbus slave RTU line
//! over a pty the way a legacy HMI would, so that the slave line's counters and the CP memory's
//! values move without hardware.
//!
//! Each cycle reads every area the slave's address map reaches (FC 01 on the M, Q, T and C rows,
//! FC 02 on the M and I rows, FC 03 and FC 04 from the first register) and writes the cycle
//! counter into one holding register (FC 06, a DB word), then waits for the next period. It runs
//! proto-core's [`Master`] engine, the same one the gateway's master lines use, as a line engine
//! on the gateway's line runtime (the same port task, timerfd and end-of-transmission estimate),
//! on any byte stream (one end of `tokio_serial::SerialStream::pair()` in the demo).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use proto_core::cpmem::{AddressMap, SlaveParams};
use proto_core::modbus::master::{Master, MasterConfig, MasterEvent, Outcome};
use proto_core::modbus::pdu::Request;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_serial::SerialPort;
use tokio_util::sync::CancellationToken;

use crate::line::runtime::{
    LineCommands, LineEngine, LineLifecycle, LineSignals, SecondPort, Stop, Unmarked,
};
use crate::line::Clock;
use crate::protocols::modbus_master::partner::spawn_line;

/// Pause between two poll cycles by default.
pub const DEFAULT_PERIOD: Duration = Duration::from_millis(500);
/// How long the simulated master waits for an answer by default (shorter than the CP's 2000 ms,
/// 003 6.4.2.1, so that a stopped gateway shows in the counters quickly).
pub const DEFAULT_REPLY_TIMEOUT: Duration = Duration::from_millis(500);
/// Bits read from each bit-table row: one timer or counter word (003 6.4.8.1: timers and
/// counters are read in steps of 16 bits).
const BITS_PER_READ: u16 = 16;
/// Registers read with FC 03 and FC 04 each cycle.
const REGISTERS_PER_READ: u16 = 8;

/// What the simulated master does.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SimMasterSettings {
    /// The slave address polled (the gateway's, 222 by default: 003 6.4.5.1).
    pub slave: u8,
    /// Baud rate and bits per character of the line, for the engine's timing.
    pub baud: u32,
    /// Start, data, parity and stop bits (11 for 8E1).
    pub bits_per_char: u8,
    /// Pause between the start of two cycles.
    pub period: Duration,
    /// Reply monitoring time.
    pub reply_timeout: Duration,
    /// The reads of one cycle.
    pub reads: Vec<Request>,
    /// The holding register the cycle counter is written to (FC 06), if any.
    pub counter_register: Option<u16>,
}

// === impl SimMasterSettings ===

impl SimMasterSettings {
    /// Polling a slave with `params` at 9600 Bd 8E1 (the CP's defaults, 003 6.4.5.1): every row of
    /// its map once a cycle, and the counter into holding register `counter_register`.
    pub fn for_slave(params: &SlaveParams, counter_register: Option<u16>) -> Self {
        Self {
            slave: params.address(),
            baud: SlaveParams::DEFAULT_BAUD_RATE,
            bits_per_char: 11,
            period: DEFAULT_PERIOD,
            reply_timeout: DEFAULT_REPLY_TIMEOUT,
            reads: reads_for(params.map()),
            counter_register,
        }
    }
}

/// One read of each area that `map` reaches: 16 bits from the start of each bit-table row, 8
/// registers from register 0 of both register tables.
pub fn reads_for(map: &AddressMap) -> Vec<Request> {
    let mut reads: Vec<Request> = map
        .coils()
        .iter()
        .map(|row| Request::ReadCoils {
            address: row.modbus_start,
            quantity: BITS_PER_READ,
        })
        .collect();
    reads.extend(map.inputs().iter().map(|row| Request::ReadDiscreteInputs {
        address: row.modbus_start,
        quantity: BITS_PER_READ,
    }));
    reads.push(Request::ReadHoldingRegisters {
        address: 0,
        quantity: REGISTERS_PER_READ,
    });
    reads.push(Request::ReadInputRegisters {
        address: 0,
        quantity: REGISTERS_PER_READ,
    });
    reads
}

/// What the simulated master has seen.
#[derive(Debug, Default)]
pub struct SimMasterStats {
    cycles: AtomicU64,
    responses: AtomicU64,
    exceptions: AtomicU64,
    failures: AtomicU64,
    last_counter: AtomicU64,
}

/// A copy of [`SimMasterStats`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SimMasterCounts {
    /// Cycles started.
    pub cycles: u64,
    /// Requests answered with data.
    pub responses: u64,
    /// Requests answered with an exception.
    pub exceptions: u64,
    /// Requests without a usable answer.
    pub failures: u64,
    /// The counter value last confirmed written.
    pub last_counter: u64,
}

impl SimMasterStats {
    /// The counts now.
    pub fn counts(&self) -> SimMasterCounts {
        SimMasterCounts {
            cycles: self.cycles.load(Ordering::Relaxed),
            responses: self.responses.load(Ordering::Relaxed),
            exceptions: self.exceptions.load(Ordering::Relaxed),
            failures: self.failures.load(Ordering::Relaxed),
            last_counter: self.last_counter.load(Ordering::Relaxed),
        }
    }
}

/// A running simulated master.
#[derive(Debug)]
pub struct SimMasterHandle {
    stats: Arc<SimMasterStats>,
    task: JoinHandle<()>,
}

impl SimMasterHandle {
    /// What it has seen so far.
    pub fn counts(&self) -> SimMasterCounts {
        self.stats.counts()
    }

    /// Waits for the task to end (after the shutdown token was cancelled or the port failed).
    pub async fn join(self) {
        if let Err(err) = self.task.await {
            tracing::error!(%err, "simulated master failed");
        }
    }
}

/// Starts the simulated master on `port` until `shutdown` is cancelled or the port fails.
pub fn spawn_sim_master<P>(
    port: P,
    settings: SimMasterSettings,
    shutdown: CancellationToken,
) -> SimMasterHandle
where
    P: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let stats = Arc::new(SimMasterStats::default());
    let bits = u64::from(settings.bits_per_char);
    let char_time = Duration::from_nanos(bits * 1_000_000_000 / u64::from(settings.baud.max(1)));
    // Ends with the shutdown or the port, whichever comes first.
    let stop = shutdown.child_token();
    let make = |clock| SimMaster::new(settings, clock, Arc::clone(&stats), stop.clone());
    let line = spawn_line("sim-master", make, Unmarked(port), char_time, stop.clone());
    let task = crate::task::spawn("sim master join", line.join());
    SimMasterHandle { stats, task }
}

impl SimMasterStats {
    /// Counts a completed request; a counter write that was answered is the last counter.
    fn record(&self, request: &Request, outcome: &Outcome) {
        let counter = match outcome {
            Outcome::Response(_) => {
                self.responses.fetch_add(1, Ordering::Relaxed);
                match request {
                    Request::WriteSingleRegister { value, .. } => Some(*value),
                    _ => None,
                }
            }
            Outcome::Exception(code) => {
                tracing::debug!(?code, ?request, "simulated master: exception");
                self.exceptions.fetch_add(1, Ordering::Relaxed);
                None
            }
            Outcome::Broadcast | Outcome::Failed(_) => {
                self.failures.fetch_add(1, Ordering::Relaxed);
                None
            }
        };
        if let Some(value) = counter {
            self.last_counter.store(u64::from(value), Ordering::Relaxed);
        }
    }
}

/// The simulated master as a line engine.
struct SimMaster {
    settings: SimMasterSettings,
    config: MasterConfig,
    master: Master,
    clock: Clock,
    stats: Arc<SimMasterStats>,
    /// The requests of the cycle not yet sent.
    queue: VecDeque<Request>,
    in_flight: bool,
    counter: u16,
    next_cycle: Instant,
    /// Cancelled when the port is lost: the master ends with its port.
    on_lost: CancellationToken,
}

// === impl SimMaster ===

impl SimMaster {
    fn new(
        settings: SimMasterSettings,
        clock: Clock,
        stats: Arc<SimMasterStats>,
        on_lost: CancellationToken,
    ) -> Self {
        let mut config = MasterConfig::rtu(settings.baud, settings.bits_per_char);
        config.reply_timeout = settings.reply_timeout;
        Self {
            settings,
            config,
            master: Master::new(config),
            clock,
            stats,
            queue: VecDeque::new(),
            in_flight: false,
            counter: 0,
            next_cycle: Instant::now(),
            on_lost,
        }
    }

    /// Nothing in flight and nothing left of the cycle: waiting for the next one.
    fn idle(&self) -> bool {
        !self.in_flight && self.master.is_idle() && self.queue.is_empty()
    }
}

impl LineEngine for SimMaster {
    fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {
        self.master = Master::new(self.config);
        self.in_flight = false;
    }

    crate::line::driver::engine_calls!(master: rx, timeout, tx);

    fn transmitted(&mut self, _written: Instant, _len: usize, end: proto_core::time::Instant) {
        self.master.handle_tx_done(end);
    }

    fn handle_events(&mut self) -> bool {
        let mut completed = false;
        while let Some(event) = self.master.poll_event() {
            if let MasterEvent::Completed {
                request, outcome, ..
            } = event
            {
                self.in_flight = false;
                completed = true;
                self.stats.record(&request, &outcome);
            }
        }
        // A completion starts the next request at once: after a reply timeout the engine is
        // idle already (the line was silent), with no deadline left to wake the loop.
        completed
    }
}

impl LineCommands for SimMaster {
    type Command = ();

    /// Starts the next cycle when its time came, and the next request of the cycle.
    fn start(&mut self, now: Instant) {
        if self.in_flight || !self.master.is_idle() {
            return;
        }
        if self.queue.is_empty() && now >= self.next_cycle {
            self.counter = self.counter.wrapping_add(1);
            self.queue.extend(self.settings.reads.iter().cloned());
            if let Some(address) = self.settings.counter_register {
                self.queue.push_back(Request::WriteSingleRegister {
                    address,
                    value: self.counter,
                });
            }
            self.stats.cycles.fetch_add(1, Ordering::Relaxed);
            self.next_cycle = now + self.settings.period;
        }
        let Some(request) = self.queue.pop_front() else {
            return;
        };
        match self
            .master
            .submit(self.clock.to_engine(now), self.settings.slave, request)
        {
            Ok(_) => self.in_flight = true,
            Err(err) => {
                tracing::warn!(%err, "simulated master: request refused by the engine");
                self.stats.failures.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    fn command(&mut self, (): (), _modem: Option<&mut dyn SerialPort>) {}

    fn refuse(&mut self, (): (), _shutting_down: bool) {}
}

impl LineLifecycle for SimMaster {
    fn stop(&mut self) -> Stop {
        Stop::AT_ONCE
    }

    fn done(&self) -> bool {
        true
    }

    fn closed(&mut self, _shutting_down: bool) {
        self.queue.clear();
        self.in_flight = false;
    }

    fn port_failed(&mut self, id: proto_core::event::EventId, reason: String) {
        tracing::warn!(event = %id, %reason, "simulated master: port closed");
        self.on_lost.cancel();
    }
}

impl LineSignals for SimMaster {
    /// The next cycle, while idle.
    fn wake(&self) -> impl std::future::Future<Output = ()> + Send + '_ {
        let at = self.idle().then_some(self.next_cycle);
        async move {
            match at {
                Some(at) => tokio::time::sleep_until(at).await,
                None => std::future::pending().await,
            }
        }
    }
}

impl SecondPort for SimMaster {}

#[cfg(test)]
mod tests {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    use super::*;

    /// A slave on the other end of `port` that answers every request with one register, except
    /// the `silent`-th request (counted from 1), which it never answers.
    async fn partner(mut port: tokio::io::DuplexStream, silent: u32) {
        let mut buf = [0u8; 256];
        let mut pending = Vec::new();
        let mut requests = 0u32;
        loop {
            let Ok(n) = port.read(&mut buf).await else {
                return;
            };
            if n == 0 {
                return;
            }
            pending.extend_from_slice(buf.get(..n).unwrap_or_default());
            // Every request of these tests is 8 bytes long (FC 03 and FC 06).
            while pending.len() >= 8 {
                pending.drain(..8);
                requests += 1;
                if requests == silent {
                    continue;
                }
                let mut reply = Vec::new();
                proto_core::modbus::rtu::encode_frame(222, &[0x03, 0x02, 0x00, 0x01], &mut reply);
                if port.write_all(&reply).await.is_err() {
                    return;
                }
            }
        }
    }

    #[tokio::test]
    async fn a_request_without_reply_does_not_stop_the_cycle() {
        // Three reads a cycle; the second request of the first cycle is never answered. After its
        // reply timeout the engine is idle at once, and the third read must still go out (it used
        // to wait for a byte from the line that never came).
        let (ours, theirs) = tokio::io::duplex(1024);
        let shutdown = CancellationToken::new();
        let read = Request::ReadHoldingRegisters {
            address: 0,
            quantity: 1,
        };
        let settings = SimMasterSettings {
            slave: 222,
            baud: 115_200,
            bits_per_char: 11,
            period: Duration::from_millis(30),
            reply_timeout: Duration::from_millis(50),
            reads: vec![read.clone(), read.clone(), read],
            counter_register: None,
        };
        let partner = tokio::spawn(partner(theirs, 2));
        let master = spawn_sim_master(ours, settings, shutdown.clone());
        let deadline = Instant::now() + Duration::from_secs(10);
        while master.counts().responses < 8 {
            assert!(
                Instant::now() < deadline,
                "the master stopped: {:?}",
                master.counts()
            );
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        let counts = master.counts();
        assert_eq!(counts.failures, 1, "{counts:?}");
        assert!(counts.cycles >= 3, "{counts:?}");
        shutdown.cancel();
        master.join().await;
        partner.abort();
    }

    #[test]
    fn one_read_per_row_and_register_table() {
        let reads = reads_for(&AddressMap::manual_example());
        let starts: Vec<(u8, u16)> = reads
            .iter()
            .map(|r| match r {
                Request::ReadCoils { address, .. } => (1, *address),
                Request::ReadDiscreteInputs { address, .. } => (2, *address),
                Request::ReadHoldingRegisters { address, .. } => (3, *address),
                Request::ReadInputRegisters { address, .. } => (4, *address),
                _ => (0, 0),
            })
            .collect();
        assert_eq!(
            starts,
            vec![
                (1, 0),
                (1, 1024),
                (1, 2048),
                (1, 4064),
                (2, 0),
                (2, 1024),
                (3, 0),
                (4, 0)
            ]
        );
    }
}
