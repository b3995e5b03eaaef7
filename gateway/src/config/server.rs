//! The Modbus TCP server: limits on connections, idle time, client networks, read-only mode and
//! write-enabled ranges.

use std::collections::BTreeMap;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::time::Duration;

use ipnet::IpNet;
use serde::Serialize;

use super::reader::{check_name, int_value, parsed_value, string_value, Cx, Fields};
use super::tag::{self, ModbusTable};

/// The Modbus TCP port (Modbus Messaging on TCP/IP Implementation Guide V1.0b, 4.1: port 502)
/// on every interface: the production default. The demo uses 127.0.0.1:5020.
pub const DEFAULT_LISTEN: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), 502);
/// Concurrent client connections; further clients are refused until one leaves.
pub const DEFAULT_MAX_CONNECTIONS: u32 = 64;
/// Upper bound of `max_connections`.
pub const MAX_MAX_CONNECTIONS: u32 = 4096;
/// A connection without a request for this long is closed.
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(60);
/// A request that has no answer after this long is answered with an exception (0x0B, "gateway
/// target device failed to respond", for a device that does not answer).
pub const DEFAULT_REQUEST_TIMEOUT: Duration = Duration::from_secs(5);
/// Accepted range of `idle_timeout`.
pub const IDLE_TIMEOUT_RANGE: (Duration, Duration) =
    (Duration::from_secs(1), Duration::from_secs(86_400));
/// Accepted range of `request_timeout`.
pub const REQUEST_TIMEOUT_RANGE: (Duration, Duration) =
    (Duration::from_millis(10), Duration::from_secs(600));
/// Writes are accepted unless `read_only` is set.
pub const DEFAULT_READ_ONLY: bool = false;
/// The Modbus/TCP Security port (MODBUS/TCP Security Protocol Specification: port 802) on every
/// interface.
pub const DEFAULT_TLS_LISTEN: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), 802);

/// The default of `max_connections_per_client`: half the places, at least one, so that one
/// client address never takes them all.
pub fn default_max_connections_per_client(max_connections: u32) -> u32 {
    max_connections.div_ceil(2).max(1)
}

/// Addresses of one unit that Modbus TCP clients may write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct UnitRange {
    pub unit_id: u8,
    /// `holding` or `coil`.
    pub table: ModbusTable,
    pub start: u16,
    pub count: u32,
}

/// Function classes a Modbus/TCP Security role may be granted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FunctionClassConfig {
    /// FC 01, 02, 03, 04, 43/14.
    Read,
    /// FC 05, 06, 15, 16 (and FC 23 with `read`).
    Write,
    /// FC 07, 08, 11, 12, 17.
    Diagnostics,
}

/// One role of `[modbus_tcp.tls.roles.<name>]`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct RoleConfig {
    /// Unit ids the role may address; empty: every unit.
    pub units: Vec<u8>,
    /// Function classes granted.
    pub functions: Vec<FunctionClassConfig>,
    /// When not empty, writes only inside these ranges.
    pub write_ranges: Vec<UnitRange>,
}

/// The `[modbus_tcp.tls]` section: Modbus/TCP Security.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ModbusTlsConfig {
    pub listen: SocketAddr,
    /// The server's certificate chain (PEM).
    pub cert: PathBuf,
    /// The server's private key (PEM).
    pub key: PathBuf,
    /// The CA certificates client certificates must chain to (PEM).
    pub ca: PathBuf,
    /// Rights by the role named in the client certificate's role extension.
    pub roles: BTreeMap<String, RoleConfig>,
}

/// The `[modbus_tcp]` section.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ModbusTcpConfig {
    /// Serve plain Modbus TCP on `listen`; false leaves only Modbus/TCP Security (if set).
    pub enabled: bool,
    pub listen: SocketAddr,
    pub max_connections: u32,
    /// Connections at once from one client address.
    pub max_connections_per_client: u32,
    /// Close a connection without requests after this long.
    #[serde(with = "humantime_serde")]
    pub idle_timeout: Duration,
    /// Answer with an exception when a request has no answer after this long.
    #[serde(with = "humantime_serde")]
    pub request_timeout: Duration,
    /// Client networks accepted; empty: every client.
    pub allowed_networks: Vec<IpNet>,
    /// Refuse every write with an exception.
    pub read_only: bool,
    /// When not empty, writes are accepted only inside these ranges.
    pub write_ranges: Vec<UnitRange>,
    /// The unit id that serves the gateway's own health (docs/diagnostics.md); `None`: off.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub diagnostic_unit: Option<u8>,
    /// Modbus/TCP Security; `None`: off.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tls: Option<ModbusTlsConfig>,
}

impl Default for ModbusTcpConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            listen: DEFAULT_LISTEN,
            max_connections: DEFAULT_MAX_CONNECTIONS,
            max_connections_per_client: default_max_connections_per_client(DEFAULT_MAX_CONNECTIONS),
            idle_timeout: DEFAULT_IDLE_TIMEOUT,
            request_timeout: DEFAULT_REQUEST_TIMEOUT,
            allowed_networks: Vec::new(),
            read_only: DEFAULT_READ_ONLY,
            write_ranges: Vec::new(),
            diagnostic_unit: None,
            tls: None,
        }
    }
}

// === impl ModbusTcpConfig ===

impl ModbusTcpConfig {
    /// Whether a client at `ip` may connect.
    pub fn allows(&self, ip: IpAddr) -> bool {
        self.allowed_networks.is_empty() || self.allowed_networks.iter().any(|n| n.contains(&ip))
    }

    /// Whether a write of `count` addresses from `start` of `table` of `unit` is allowed by
    /// `read_only` and `write_ranges`.
    pub fn allows_write(&self, unit: u8, table: ModbusTable, start: u16, count: u32) -> bool {
        !self.read_only
            && (self.write_ranges.is_empty()
                || self.write_ranges.iter().any(|r| {
                    r.unit_id == unit
                        && r.table == table
                        && start >= r.start
                        && u32::from(start) + count <= u32::from(r.start) + r.count
                }))
    }

    pub(crate) fn read(cx: &mut Cx, mut f: Fields<'_>) -> Self {
        let (ilo, ihi) = IDLE_TIMEOUT_RANGE;
        let (rlo, rhi) = REQUEST_TIMEOUT_RANGE;
        let enabled = f.bool_or(cx, "enabled", true);
        let listen = f.parsed_or(
            cx,
            "listen",
            "socket address (e.g. \"0.0.0.0:502\")",
            DEFAULT_LISTEN,
        );
        let max_connections = f.int_or(
            cx,
            "max_connections",
            1..=MAX_MAX_CONNECTIONS,
            DEFAULT_MAX_CONNECTIONS,
            "",
        );
        let config = Self {
            enabled,
            listen,
            max_connections,
            max_connections_per_client: f.int_or(
                cx,
                "max_connections_per_client",
                1..=MAX_MAX_CONNECTIONS,
                default_max_connections_per_client(max_connections),
                "",
            ),
            idle_timeout: f.duration_or(cx, "idle_timeout", ilo..=ihi, DEFAULT_IDLE_TIMEOUT, ""),
            request_timeout: f.duration_or(
                cx,
                "request_timeout",
                rlo..=rhi,
                DEFAULT_REQUEST_TIMEOUT,
                "",
            ),
            allowed_networks: f
                .array(cx, "allowed_networks")
                .into_iter()
                .filter_map(|(path, v)| {
                    parsed_value::<IpNet>(cx, v, &path, "network (e.g. \"10.0.0.0/8\")")
                })
                .collect(),
            read_only: f.bool_or(cx, "read_only", DEFAULT_READ_ONLY),
            write_ranges: unit_ranges(cx, &mut f),
            diagnostic_unit: f.int(cx, "diagnostic_unit", 1..=u8::MAX, ""),
            tls: f.table(cx, "tls").map(|t| ModbusTlsConfig::read(cx, t)),
        };
        f.finish(cx);
        config
    }
}

// === impl ModbusTlsConfig ===

impl ModbusTlsConfig {
    fn read(cx: &mut Cx, mut f: Fields<'_>) -> Self {
        let listen = f.parsed_or(
            cx,
            "listen",
            "socket address (e.g. \"0.0.0.0:802\")",
            DEFAULT_TLS_LISTEN,
        );
        let mut file = |cx: &mut Cx, key| {
            f.required_string(cx, key)
                .map(PathBuf::from)
                .unwrap_or_default()
        };
        let (cert, key, ca) = (file(cx, "cert"), file(cx, "key"), file(cx, "ca"));
        let mut roles = BTreeMap::new();
        for (name, path, v) in f.named_tables(cx, "roles") {
            check_name(cx, &path, &name);
            if let Some(t) = Fields::of(cx, v, path) {
                roles.insert(name, RoleConfig::read(cx, t));
            }
        }
        f.finish(cx);
        Self {
            listen,
            cert,
            key,
            ca,
            roles,
        }
    }
}

// === impl RoleConfig ===

impl RoleConfig {
    fn read(cx: &mut Cx, mut f: Fields<'_>) -> Self {
        let mut units = Vec::new();
        for (path, v) in f.array(cx, "units") {
            units.extend(int_value::<u8>(cx, v, &path, 0..=u8::MAX, ""));
        }
        let mut functions = Vec::new();
        for (path, v) in f.array(cx, "functions") {
            let Some(name) = string_value(cx, v, &path) else {
                continue;
            };
            match name.as_str() {
                "read" => functions.push(FunctionClassConfig::Read),
                "write" => functions.push(FunctionClassConfig::Write),
                "diagnostics" => functions.push(FunctionClassConfig::Diagnostics),
                other => cx.issue(
                    path,
                    format!("unknown function class {other:?}: use \"read\", \"write\" or \"diagnostics\""),
                ),
            }
        }
        let write_ranges = unit_ranges(cx, &mut f);
        f.finish(cx);
        Self {
            units,
            functions,
            write_ranges,
        }
    }
}

/// The `write_ranges` array of a table: writable ranges, each of one unit.
fn unit_ranges(cx: &mut Cx, f: &mut Fields<'_>) -> Vec<UnitRange> {
    let mut write_ranges = Vec::new();
    for (path, v) in f.array(cx, "write_ranges") {
        let Some(mut t) = Fields::of(cx, v, path.clone()) else {
            continue;
        };
        let unit_id = t.required_int::<u8>(cx, "unit_id", 1..=u8::MAX, "");
        let range = tag::range_fields(cx, &mut t);
        t.finish(cx);
        if let Some(r) = range {
            if !r.table.is_writable() {
                cx.issue(
                    format!("{path}.table"),
                    "only \"holding\" and \"coil\" can be written",
                );
            }
            if let Some(unit_id) = unit_id {
                write_ranges.push(UnitRange {
                    unit_id,
                    table: r.table,
                    start: r.start,
                    count: r.count,
                });
            }
        }
    }
    write_ranges
}
