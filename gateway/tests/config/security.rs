//! `[modbus_tcp]` security keys: the per-client cap, the plain server's switch, Modbus/TCP
//! Security with its roles.

use super::*;

use gateway::config::{FunctionClassConfig, ModbusTable, UnitRange};

#[test]
fn one_client_address_gets_half_the_places_by_default() {
    let c = parse("");
    assert!(c.modbus_tcp.enabled);
    assert_eq!(c.modbus_tcp.max_connections_per_client, 32);
    assert_eq!(c.modbus_tcp.tls, None);
    let c = parse("[modbus_tcp]\nmax_connections = 5\n");
    assert_eq!(c.modbus_tcp.max_connections_per_client, 3);
    let c = parse("[modbus_tcp]\nmax_connections = 1\n");
    assert_eq!(c.modbus_tcp.max_connections_per_client, 1);
    let c = parse("[modbus_tcp]\nenabled = false\nmax_connections_per_client = 4\n");
    assert!(!c.modbus_tcp.enabled);
    assert_eq!(c.modbus_tcp.max_connections_per_client, 4);
}

#[test]
fn modbus_tcp_security_reads_files_and_roles() {
    let c = parse(
        r#"
[modbus_tcp.tls]
cert = "/etc/gateway/tls/server.crt"
key = "/etc/gateway/tls/server.key"
ca = "/etc/gateway/tls/ca.crt"

[modbus_tcp.tls.roles.operator]
units = [2, 17]
functions = ["read", "write"]
write_ranges = [{ unit_id = 2, table = "holding", start = 9001, count = 2 }]

[modbus_tcp.tls.roles.viewer]
functions = ["read"]
"#,
    );
    let tls = c.modbus_tcp.tls.expect("tls");
    // MODBUS/TCP Security: port 802.
    assert_eq!(tls.listen, "0.0.0.0:802".parse::<SocketAddr>().unwrap());
    assert_eq!(
        tls.cert,
        std::path::Path::new("/etc/gateway/tls/server.crt")
    );
    let operator = &tls.roles["operator"];
    assert_eq!(operator.units, [2, 17]);
    assert_eq!(
        operator.functions,
        [FunctionClassConfig::Read, FunctionClassConfig::Write]
    );
    assert_eq!(
        operator.write_ranges,
        [UnitRange {
            unit_id: 2,
            table: ModbusTable::Holding,
            start: 9001,
            count: 2
        }]
    );
    let viewer = &tls.roles["viewer"];
    assert!(viewer.units.is_empty());
    assert_eq!(viewer.functions, [FunctionClassConfig::Read]);
}

#[test]
fn modbus_tcp_security_mistakes_are_reported() {
    one_issue(
        "[modbus_tcp.tls]\nkey = \"k\"\nca = \"c\"\n",
        "modbus_tcp.tls.cert",
        "missing",
    );
    one_issue(
        "[modbus_tcp.tls]\ncert = \"c\"\nkey = \"k\"\nca = \"a\"\n[modbus_tcp.tls.roles.op]\nfunctions = [\"erase\"]\n",
        "modbus_tcp.tls.roles.op.functions[0]",
        "unknown function class",
    );
    one_issue(
        "[modbus_tcp.tls]\ncert = \"c\"\nkey = \"k\"\nca = \"a\"\n[modbus_tcp.tls.roles.op]\nwrite_ranges = [{ unit_id = 2, table = \"input\", start = 0, count = 1 }]\n",
        "modbus_tcp.tls.roles.op.write_ranges[0].table",
        "can be written",
    );
    one_issue(
        "[modbus_tcp.tls]\ncert = \"c\"\nkey = \"k\"\nca = \"a\"\npassword = \"x\"\n",
        "modbus_tcp.tls.password",
        "unknown",
    );
    one_issue(
        "[modbus_tcp]\nlisten = \"0.0.0.0:802\"\n[modbus_tcp.tls]\ncert = \"c\"\nkey = \"k\"\nca = \"a\"\n",
        "modbus_tcp.tls.listen",
        "same address",
    );
}

#[test]
fn api_changes_name_ports_and_state_files_in_the_configured_directories() {
    let c = parse("");
    assert_eq!(c.gateway.port_dirs, [PathBuf::from("/dev")]);
    assert_eq!(c.gateway.state_dirs, [PathBuf::from("/var/lib/gateway")]);
    let c = parse("[gateway]\nport_dirs = [\"/dev\", \"/run/serial\"]\nstate_dirs = []\n");
    assert_eq!(
        c.gateway.port_dirs,
        [PathBuf::from("/dev"), PathBuf::from("/run/serial")]
    );
    assert!(c.gateway.state_dirs.is_empty());
}
