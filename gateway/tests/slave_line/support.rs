//! What the slave line tests share: a slave line on one end of a real pty pair with a tokio-modbus
//! RTU client on the other, a Modbus TCP server on 127.0.0.1 port 0, a CP memory with known
//! contents, timing helpers.

use std::future::Future;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, RwLock};
use std::time::Duration;

use gateway::cpmem::{CpMemoryUnit, SharedCpMemory};
use gateway::line::LineHandle;
use gateway::modbus_tcp::{bind, serve, ServerOptions, ServerStats};
use gateway::protocols::{spawn_modbus_slave_line, SlaveLineSettings};
use gateway::serial::PortSettings;
use gateway::unit::UnitMap;
use proto_core::cpmem::{AddressMap, MemoryLayout, OperatingMode, SlaveParams, WriteLimits};
use tokio::task::JoinHandle;
use tokio_modbus::client::Context;
use tokio_modbus::Slave;
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

/// How long a test waits for something that should happen at once.
pub(crate) const PATIENCE: Duration = Duration::from_secs(5);

/// The gateway's slave address: the CP's default (003 6.4.5.1).
pub(crate) const ADDRESS: u8 = 222;

/// The Modbus TCP unit id of the memory in these tests.
pub(crate) const UNIT: u8 = 5;

/// The manual's example map (003 6.4.8) with FC 04 on a second base, DB 801, and write limits:
/// MB 1000..1100, QB 100..227, DB 800 only.
pub(crate) fn test_map() -> AddressMap {
    let example = AddressMap::manual_example();
    let limits = WriteLimits {
        memory: Some((1000, 1100)),
        outputs: Some((100, 227)),
        data_blocks: Some((800, 800)),
    };
    AddressMap::new(example.coils(), example.inputs(), 800, 801, limits).expect("valid map")
}

/// Memory with a pattern in every area the map reaches.
pub(crate) fn filled_memory() -> SharedCpMemory {
    let memory = SharedCpMemory::new(MemoryLayout::default());
    memory.update(|m| {
        m.m_mut()[1000] = 0b1010_0101;
        m.m_mut()[1001] = 0x0F;
        m.q_mut()[100] = 0b0000_0110;
        m.i_mut()[100] = 0x81;
        m.i_mut()[101] = 0x40;
        m.timers_mut()[100] = 0x8001;
        m.counters_mut()[200] = 0x0003;
        m.counters_mut()[201] = 0xFF00;
        let db800 = m.db_mut(800).expect("DB 800");
        db800[0] = 0x1111;
        db800[1] = 0x2222;
        db800[2] = 0x3333;
        let db801 = m.db_mut(801).expect("DB 801");
        db801[0] = 0xA0A0;
        db801[1] = 0xB1B1;
        db801[388] = 0x0388;
    });
    memory
}

/// A pty pair: the outside master's end, the line's path, and the line end's first handle, kept
/// open so that the master's end does not see a hang-up before the line opens the path.
pub(crate) fn pty() -> (SerialStream, String, SerialStream) {
    let (outside, line_end) = SerialStream::pair().expect("pty pair");
    let path = line_end.name().expect("pty path");
    (outside, path, line_end)
}

/// A slave line serving `memory` and a tokio-modbus RTU client talking to it.
pub(crate) struct Rig {
    pub(crate) line: LineHandle,
    pub(crate) memory: SharedCpMemory,
    pub(crate) client: Context,
    pub(crate) shutdown: CancellationToken,
    _keep: SerialStream,
}

impl Rig {
    /// A line with [`test_map`] on a fresh pty at 19200 Bd.
    pub(crate) async fn start(memory: SharedCpMemory) -> Self {
        Self::start_with(memory, test_map()).await
    }

    pub(crate) async fn start_with(memory: SharedCpMemory, map: AddressMap) -> Self {
        let (outside, path, keep) = pty();
        let params = SlaveParams::new(ADDRESS, OperatingMode::Normal, 1, map).expect("params");
        let mut settings = SlaveLineSettings::new("hmi", PortSettings::new(path, 19200), params);
        settings.reopen_min = Duration::from_millis(50);
        settings.reopen_max = Duration::from_millis(200);
        let shutdown = CancellationToken::new();
        let line = spawn_modbus_slave_line(settings, memory.clone(), shutdown.clone());
        eventually("the port to open", || line.status().port_open).await;
        let client = tokio_modbus::client::rtu::attach_slave(outside, Slave(ADDRESS));
        Self {
            line,
            memory,
            client,
            shutdown,
            _keep: keep,
        }
    }

    /// Stops the line and waits for it.
    pub(crate) async fn stop(self) {
        self.shutdown.cancel();
        within("the line to stop", self.line.join()).await;
    }
}

/// A Modbus TCP server on 127.0.0.1 port 0 serving `unit` under [`UNIT`], and a client of it.
pub(crate) struct Tcp {
    pub(crate) client: Context,
    shutdown: CancellationToken,
    task: JoinHandle<std::io::Result<()>>,
}

impl Tcp {
    pub(crate) async fn start(unit: CpMemoryUnit) -> Self {
        let mut units = UnitMap::new();
        units.insert(UNIT, Arc::new(unit));
        let listener = bind(SocketAddr::from(([127, 0, 0, 1], 0))).expect("bind");
        let addr = listener.local_addr().expect("local address");
        let shutdown = CancellationToken::new();
        let task = tokio::spawn(serve(
            listener,
            Arc::new(RwLock::new(units)),
            ServerOptions::default(),
            shutdown.clone(),
            Arc::new(ServerStats::new()),
        ));
        let client = tokio_modbus::client::tcp::connect_slave(addr, Slave(UNIT))
            .await
            .expect("connect");
        Self {
            client,
            shutdown,
            task,
        }
    }

    pub(crate) async fn stop(self) {
        drop(self.client);
        self.shutdown.cancel();
        let result = within("the server to stop", self.task).await;
        assert!(matches!(result, Ok(Ok(()))), "{result:?}");
    }
}

/// Waits up to [`PATIENCE`] for `check` to hold.
pub(crate) async fn eventually(what: &str, mut check: impl FnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while !check() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// Awaits `future` for at most [`PATIENCE`].
pub(crate) async fn within<T>(what: &str, future: impl Future<Output = T>) -> T {
    tokio::time::timeout(PATIENCE, future)
        .await
        .unwrap_or_else(|_| panic!("timed out waiting for {what}"))
}

/// A fresh path in the system's temporary directory (removed by the test).
pub(crate) fn temp_path(name: &str) -> PathBuf {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    std::env::temp_dir().join(format!("gw-cpmem-{}-{nanos}-{name}", std::process::id()))
}

/// The bits of `bytes` from bit 0 of the first byte, `n` of them.
pub(crate) fn bits(bytes: &[u8], n: usize) -> Vec<bool> {
    (0..n).map(|k| bytes[k / 8] & (1 << (k % 8)) != 0).collect()
}
