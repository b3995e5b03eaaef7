//! End to end on the binary: a configuration change of a Modbus TCP limit (REST `PUT
//! /api/v1/config`) applies to new connections and to the next request of the open ones without
//! closing them; only a changed listen address restarts the server.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use gateway_tests::{temp_dir, Gateway, SocatLink};
use serde_json::{json, Value};
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::prelude::Slave;

/// The mailbox of the ASCII line: answered by the gateway itself, no device behind it.
const UNIT: u8 = 5;

/// Connections held open through every change.
const HELD: usize = 4;

async fn connect(addr: SocketAddr) -> std::io::Result<Context> {
    tokio::time::timeout(
        Duration::from_secs(5),
        tcp::connect_slave(addr, Slave(UNIT)),
    )
    .await
    .unwrap_or_else(|_| Err(std::io::Error::other("connect timed out")))
}

/// One read of the receive block's first register: whether the connection answered.
async fn answers(client: &mut Context) -> bool {
    matches!(
        tokio::time::timeout(Duration::from_secs(5), client.read_holding_registers(0, 1)).await,
        Ok(Ok(Ok(_)))
    )
}

async fn put(http: &reqwest::Client, base: &str, config: &Value) -> Value {
    let reply = http
        .put(format!("{base}/api/v1/config"))
        .json(config)
        .send()
        .await
        .expect("PUT config");
    let status = reply.status();
    let body: Value = reply.json().await.expect("JSON");
    assert_eq!(status.as_u16(), 200, "{body:#}");
    body
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_changed_limit_keeps_the_open_connections_and_applies_to_new_ones() {
    let dir = temp_dir("modbus_tcp_limits");
    let link = SocatLink::new(&dir, "ascii");
    let file = dir.join("gateway.toml");
    std::fs::write(
        &file,
        format!(
            r#"
[gateway]
name = "limits"

[modbus_tcp]
listen = "127.0.0.1:0"
max_connections = 64
max_connections_per_client = 8

[http]
insecure_allow_unauthenticated_changes = true

[lines.ascii]
port = "{port}"
protocol = "ascii"
end_criterion = "end-chars"
end_chars = [0x03]
unit_id = {UNIT}
"#,
            port = link.a.display()
        ),
    )
    .expect("write config");
    let mut gw = Gateway::run(&file);
    let base = format!("http://{}", gw.http.expect("http"));
    let http = reqwest::Client::new();
    let mut config: Value = http
        .get(format!("{base}/api/v1/config"))
        .send()
        .await
        .expect("GET config")
        .json()
        .await
        .expect("JSON");

    let mut held = Vec::new();
    for _ in 0..HELD {
        let mut client = connect(gw.modbus_tcp).await.expect("connect");
        assert!(answers(&mut client).await, "a new connection answers");
        held.push(client);
    }

    // Each change touches [modbus_tcp]; none restarts the server or drops a held connection.
    let changes: [(&str, Value); 5] = [
        ("max_connections", json!(32)),
        ("idle_timeout", json!("30s")),
        ("allowed_networks", json!(["127.0.0.0/8", "10.0.0.0/8"])),
        (
            "write_ranges",
            json!([{ "unit_id": UNIT, "table": "holding", "start": 0, "count": 1 }]),
        ),
        ("max_connections_per_client", json!(HELD)),
    ];
    for (key, value) in changes {
        config["modbus_tcp"][key] = value;
        let body = put(&http, &base, &config).await;
        assert_eq!(
            body["applied"]["servers_restarted"],
            json!([]),
            "{key}: {body:#}"
        );
        for (i, client) in held.iter_mut().enumerate() {
            assert!(
                answers(client).await,
                "held connection {i} stopped answering after the change of {key}"
            );
        }
    }

    // The per-client cap is now the held count: a fifth connection from the same address is
    // refused (closed at accept), the held ones still answer.
    let refused = match connect(gw.modbus_tcp).await {
        Ok(mut client) => !answers(&mut client).await,
        Err(_) => true,
    };
    assert!(
        refused,
        "a connection over the lowered per-client cap was served"
    );
    for (i, client) in held.iter_mut().enumerate() {
        assert!(
            answers(client).await,
            "held connection {i} after the refusal"
        );
    }
    // Another address of the loopback network still gets a place of its own.
    let other: SocketAddr = SocketAddr::new([127, 0, 0, 2].into(), gw.modbus_tcp.port());
    let mut second = tokio::time::timeout(Duration::from_secs(5), async {
        let socket = tokio::net::TcpSocket::new_v4()?;
        socket.bind(SocketAddr::new([127, 0, 0, 2].into(), 0))?;
        let stream = socket.connect(gw.modbus_tcp).await?;
        Ok::<_, std::io::Error>(tcp::attach_slave(stream, Slave(UNIT)))
    })
    .await
    .expect("connect in time")
    .expect("connect from 127.0.0.2");
    let _ = other;
    assert!(answers(&mut second).await, "127.0.0.2 has its own places");
    drop(second);

    // The write policy applies to the next request of an open connection: read-only refuses the
    // held connection's write with exception 01.
    config["modbus_tcp"]["read_only"] = json!(true);
    let body = put(&http, &base, &config).await;
    assert_eq!(body["applied"]["servers_restarted"], json!([]), "{body:#}");
    let write = tokio::time::timeout(Duration::from_secs(5), held[0].write_single_register(0, 1))
        .await
        .expect("answer in time")
        .expect("transport");
    assert_eq!(write, Err(tokio_modbus::ExceptionCode::IllegalFunction));
    assert!(answers(&mut held[1]).await, "reads still answer");

    let output = gw.output();
    assert_eq!(
        output.matches("Modbus TCP server restarted").count(),
        0,
        "{output}"
    );
    assert!(
        output.contains("Modbus TCP limits applied to the running server"),
        "{output}"
    );

    // A changed listen address restarts the server: the held connections close, the new address
    // serves.
    config["modbus_tcp"]["listen"] = json!("127.0.0.3:0");
    let body = put(&http, &base, &config).await;
    assert_eq!(
        body["applied"]["servers_restarted"],
        json!(["modbus_tcp"]),
        "{body:#}"
    );
    let line = gw.wait_for("Modbus TCP server restarted", Duration::from_secs(10));
    let local: SocketAddr = line
        .split("local=")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|addr| addr.parse().ok())
        .unwrap_or_else(|| panic!("no address in {line:?}"));
    assert_eq!(local.ip().to_string(), "127.0.0.3");
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut closed = false;
    while !closed && Instant::now() < deadline {
        closed = !answers(&mut held[2]).await;
    }
    assert!(closed, "a held connection of the old server still answers");
    let mut fresh = connect(local).await.expect("connect to the new address");
    assert!(answers(&mut fresh).await, "the restarted server answers");
}
