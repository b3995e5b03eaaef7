//! The simulators on real ptys (`tokio_serial::SerialStream::pair()`): the simulator serves one
//! end, the test writes requests on the other and reads the answers.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use gateway::sim::altivar::AltivarSim;
use gateway::sim::ksvario::{Datum, KsVarioSim};
use gateway::sim::{
    run, serve_modbus, DeviceKind, Faults, ModbusDevice, Parity, SimArgs, SimError,
};
use proto_core::modbus::rtu::CharTiming;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::task::JoinHandle;
use tokio::time::timeout;
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

use crate::{frame, hex};

/// Longest wait for an answer: a guard against hanging, not a speed requirement.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a test listens to be sure nothing comes: far longer than the simulator's turnaround
/// (t3.5 at 19200 Bd is about 2 ms).
const SILENCE: Duration = Duration::from_millis(300);

/// A simulator serving one end of a pty pair; the other end is the test's.
struct Line {
    port: SerialStream,
    shutdown: CancellationToken,
    task: JoinHandle<Result<(), SimError>>,
}

// === impl Line ===

impl Line {
    fn start(device: impl ModbusDevice + 'static) -> Self {
        let (port, sim_end) = SerialStream::pair().expect("pty pair");
        let shutdown = CancellationToken::new();
        let timing = CharTiming::new(19_200, 11);
        let task = tokio::spawn(serve_modbus(sim_end, device, timing, shutdown.clone()));
        Self {
            port,
            shutdown,
            task,
        }
    }

    /// Writes `request` and reads an answer of `len` bytes.
    async fn exchange(&mut self, request: &[u8], len: usize) -> Vec<u8> {
        self.port.write_all(request).await.expect("write request");
        let mut answer = vec![0u8; len];
        timeout(ANSWER_TIMEOUT, self.port.read_exact(&mut answer))
            .await
            .unwrap_or_else(|_| panic!("no answer to {request:02X?}"))
            .expect("read answer");
        answer
    }

    /// Writes `request` and checks that nothing comes back.
    async fn silence(&mut self, request: &[u8]) {
        self.port.write_all(request).await.expect("write request");
        let mut byte = [0u8; 1];
        let read = timeout(SILENCE, self.port.read(&mut byte)).await;
        assert!(
            read.is_err(),
            "unexpected answer {byte:02X?} to {request:02X?}"
        );
    }

    async fn stop(self) {
        self.shutdown.cancel();
        let result = timeout(ANSWER_TIMEOUT, self.task)
            .await
            .expect("simulator stops")
            .expect("task");
        assert!(result.is_ok(), "{result:?}");
    }
}

#[tokio::test]
async fn altivar_manual_frames_over_a_pty() {
    for vector in super::altivar::vectors() {
        let mut line = Line::start((vector.setup)());
        match &vector.response {
            Some(response) => {
                let answer = line.exchange(&vector.request, response.len()).await;
                assert_eq!(&answer, response, "{}", vector.name);
            }
            None => line.silence(&vector.request).await,
        }
        line.stop().await;
    }
}

#[tokio::test]
async fn ksvario_manual_frames_over_a_pty() {
    let mut line = Line::start(KsVarioSim::default());
    for (name, request, response) in super::ksvario::vectors() {
        let answer = line.exchange(&request, response.len()).await;
        assert_eq!(answer, response, "{name}");
    }
    line.stop().await;
}

#[tokio::test]
async fn silence_for_other_address_and_bad_crc_then_answers_again() {
    let mut line = Line::start(AltivarSim::default());
    line.silence(&hex("03 03 0C 1E 00 04 26 BD")).await;
    line.silence(&hex("02 03 0C 1E 00 04 27 6D")).await;
    // A frame whose length the function code does not tell (an unknown function) ends with the
    // t3.5 silence, and is answered with exception 01.
    assert_eq!(
        line.exchange(&frame("02 64 00 01"), 5).await,
        frame("02 E4 01")
    );
    let answer = line.exchange(&hex("02 03 0C 1E 00 04 27 6C"), 13).await;
    assert_eq!(answer, hex("02 03 08 00 28 02 58 01 F4 00 00 52 B0"));
    line.stop().await;
}

#[tokio::test]
async fn two_frames_in_one_write_are_both_answered() {
    let mut line = Line::start(AltivarSim::default());
    let mut both = hex("02 06 23 29 00 0D 92 70");
    both.extend_from_slice(&hex("02 03 0C 1E 00 04 27 6C"));
    let answer = line.exchange(&both, 8 + 13).await;
    assert_eq!(answer.get(..8), Some(&hex("02 06 23 29 00 0D 92 70")[..]));
    assert_eq!(
        answer.get(8..),
        Some(&hex("02 03 08 00 28 02 58 01 F4 00 00 52 B0")[..])
    );
    line.stop().await;
}

#[tokio::test]
async fn broadcast_is_applied_silently_over_a_pty() {
    let sim = Arc::new(Mutex::new(KsVarioSim::default()));
    let mut line = Line::start(Arc::clone(&sim));
    line.silence(&frame("00 10 9A AE 00 04 08 43 5E 00 00 43 A6 80 00"))
        .await;
    let answer = line.exchange(&frame("11 03 0D 57 00 02"), 9).await;
    assert_eq!(answer, frame("11 03 04 00 DE 01 4D"));
    assert_eq!(sim.lock().unwrap().datum(3416), Some(Datum::Value(333.0)));
    line.stop().await;
}

#[tokio::test]
async fn listen_only_and_restart_over_a_pty() {
    let mut line = Line::start(KsVarioSim::default());
    line.silence(&frame("11 08 00 04 00 00")).await;
    line.silence(&frame("11 04 03 EC 00 03")).await;
    line.silence(&frame("11 08 00 01 00 00")).await;
    let answer = line.exchange(&frame("11 04 03 EC 00 03"), 11).await;
    assert_eq!(answer, frame("11 04 06 04 2A 00 8C 10 3E"));
    // FC 06 to a float address is refused.
    let answer = line.exchange(&frame("11 06 9A AE 43 5E"), 5).await;
    assert_eq!(answer, frame("11 86 02"));
    line.stop().await;
}

#[tokio::test]
async fn faults_change_while_serving() {
    let sim = Arc::new(Mutex::new(AltivarSim::default()));
    let mut line = Line::start(Arc::clone(&sim));
    let request = hex("02 03 0C 1E 00 04 27 6C");
    sim.lock().unwrap().set_faults(Faults {
        silent: true,
        ..Faults::default()
    });
    line.silence(&request).await;
    sim.lock().unwrap().set_faults(Faults {
        wrong_address: true,
        ..Faults::default()
    });
    let answer = line.exchange(&request, 13).await;
    assert_eq!(answer, frame("03 03 08 00 28 02 58 01 F4 00 00"));
    sim.lock().unwrap().set_faults(Faults::default());
    assert_eq!(
        line.exchange(&request, 13).await,
        hex("02 03 08 00 28 02 58 01 F4 00 00 52 B0")
    );
    line.stop().await;
}

/// `gateway sim`'s entry point on a pty path: the test keeps the pty's master and hands the
/// slave's path to `run`, which opens it like any serial port.
#[tokio::test]
async fn run_opens_a_port_by_path() {
    let (mut port, slave) = SerialStream::pair().expect("pty pair");
    let path = slave.name().expect("pty name");
    let args = SimArgs {
        device: vec![DeviceKind::named("ksvario").expect("a model")],
        port: path,
        address: Vec::new(),
        also_address: Vec::new(),
        baud: 19_200,
        parity: Parity::Even,
        data_bits: 8,
        stop_bits: 1,
        every: Duration::from_secs(1),
        fault: None,
        fault_delay: Duration::from_secs(1),
        ignore_function: None,
    };
    let shutdown = CancellationToken::new();
    let task = tokio::spawn(run(args, shutdown.clone()));
    // The port may flush its input when it opens: ask until the simulator answers.
    let request = frame("11 04 03 EC 00 03");
    let mut answer = vec![0u8; 11];
    let mut answered = false;
    for _ in 0..50 {
        port.write_all(&request).await.unwrap();
        if let Ok(read) = timeout(Duration::from_millis(200), port.read_exact(&mut answer)).await {
            read.unwrap();
            answered = true;
            break;
        }
    }
    assert!(
        answered,
        "the simulator never answered on {:?}",
        slave.name()
    );
    assert_eq!(answer, frame("11 04 06 04 2A 00 8C 10 3E"));
    shutdown.cancel();
    assert!(timeout(ANSWER_TIMEOUT, task)
        .await
        .unwrap()
        .unwrap()
        .is_ok());
    drop(slave);
}

#[tokio::test]
async fn gateway_sim_runs_the_telegram_partners_on_a_port_path() {
    // 3964R: the partner's own telegram starts with STX (02h); ASCII: it ends with ETX (03h).
    for (device, marker) in [(DeviceKind::Proc3964r, 0x02u8), (DeviceKind::Ascii, 0x03u8)] {
        let (mut master, slave) = SerialStream::pair().unwrap();
        let path = SerialPort::name(&slave).unwrap();
        let args = SimArgs {
            device: vec![device],
            port: path,
            address: Vec::new(),
            also_address: Vec::new(),
            baud: 9600,
            parity: Parity::Even,
            data_bits: 8,
            stop_bits: 1,
            every: Duration::from_millis(50),
            fault: None,
            fault_delay: Duration::from_secs(1),
            ignore_function: None,
        };
        let shutdown = CancellationToken::new();
        let sim = tokio::spawn(run(args, shutdown.clone()));
        let mut seen = Vec::new();
        let found = timeout(Duration::from_secs(10), async {
            let mut buf = [0u8; 64];
            loop {
                let n = master.read(&mut buf).await.unwrap();
                seen.extend_from_slice(&buf[..n]);
                if seen.contains(&marker) {
                    return;
                }
            }
        })
        .await;
        assert!(
            found.is_ok(),
            "{device}: no telegram from the partner: {seen:02X?}"
        );
        shutdown.cancel();
        let _ = sim.await;
        drop(slave);
    }
}
