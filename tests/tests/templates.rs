//! End to end on the binary: two meters on one line from one template, one device taking it from
//! the config's `[templates]` and one from the shipped file `deploy/templates/meter.toml` (found
//! through `[gateway] template_dirs`), both answered by `gateway sim --device meter` on a pty
//! (slaves 30 and 31 on one bus) and both served over Modbus TCP, REST and zenoh; the second
//! device replaces one template tag with its own. `GET /config` shows the templates as written.

use std::time::{Duration, Instant};

use gateway_tests::Gateway;
use serde_json::Value;
use tokio_modbus::client::{tcp, Reader};
use tokio_modbus::prelude::Slave;

/// The shipped template file turned into a `[templates.NAME]` table of a config.
fn inline_template(name: &str, file_text: &str) -> String {
    format!(
        "[templates.{name}]\n{}",
        file_text.replace("[[poll]]", &format!("[[templates.{name}.poll]]"))
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_devices_from_one_template_are_served_everywhere() {
    let dir = gateway_tests::temp_dir("templates");
    let shipped =
        std::fs::read_to_string(gateway_tests::repo_root().join("deploy/templates/meter.toml"))
            .expect("the shipped template");
    std::fs::create_dir_all(dir.join("templates")).expect("templates dir");
    std::fs::write(dir.join("templates/meter.toml"), &shipped).expect("write template");
    let link = gateway_tests::SocatLink::new(&dir, "meters");
    let _meters = gateway_tests::start_sim(&[
        "--device",
        "meter",
        "--port",
        link.b.to_str().expect("utf-8 path"),
        "--address",
        "30",
        "--also-address",
        "31",
    ]);
    let inline = inline_template("meter_here", &shipped);
    let config = |zenoh_port: u16| {
        format!(
            r#"
[gateway]
name = "tpl"
# relative: from this file's directory
template_dirs = ["templates"]

[modbus_tcp]
listen = "127.0.0.1:0"

[zenoh]
mode = "peer"
listen = ["tcp/127.0.0.1:{zenoh_port}"]
connect = []
multicast_scouting = false

[lines.meters]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"

# From the file templates/meter.toml.
[lines.meters.devices.m30]
template = "meter"
address = 30
unit_id = 30

# From [templates.meter_here] below; its temperature replaced by the device's own (in kelvin).
[lines.meters.devices.m31]
template = "meter_here"
address = 31
unit_id = 31
tags = [
  {{ name = "temperature", table = "input", address = 8, type = "u16", scale = 0.1, unit = "K", description = "raw kelvin" }},
]

{inline}
"#,
            port = link.a.display(),
        )
    };
    let gw = Gateway::run_on_free_zenoh_port(&dir.join("gateway.toml"), config);
    let base = format!("http://{}", gw.http.expect("HTTP"));
    let client = reqwest::Client::builder()
        .no_proxy()
        .timeout(Duration::from_secs(30))
        .build()
        .expect("HTTP client");
    let tag = |device: &str, tag: &str| {
        let url = format!("{base}/api/v1/lines/meters/devices/{device}/tags/{tag}");
        let client = client.clone();
        async move {
            let r = client.get(url).send().await.expect("GET");
            assert_eq!(r.status(), 200);
            r.json::<Value>().await.expect("JSON")
        }
    };

    // Both devices polled by the template's poll group.
    let deadline = Instant::now() + Duration::from_secs(60);
    for device in ["m30", "m31"] {
        loop {
            let v = tag(device, "power_factor").await;
            if v["quality"] == "good" {
                break;
            }
            assert!(Instant::now() < deadline, "{device} was never polled: {v}");
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }

    // --- REST: the template's tags on both, the device's own temperature on m31 ---
    assert_eq!(
        tag("m30", "temperature").await["value"].to_string(),
        "19.95"
    );
    assert_eq!(tag("m30", "temperature").await["unit"], "degC");
    let own = tag("m31", "temperature").await;
    assert_eq!(own["value"].to_string(), "293.1", "{own}");
    assert_eq!(own["unit"], "K");
    assert_eq!(own["description"], "raw kelvin", "{own}");
    assert_eq!(
        tag("m30", "energy").await["description"],
        "energy imported",
        "the template's description"
    );
    assert_eq!(
        tag("m30", "serial").await["value"],
        tag("m31", "serial").await["value"]
    );
    assert_eq!(
        tag("m31", "power_factor").await["value"].to_string(),
        "0.95"
    );

    // --- Modbus TCP: each unit id answers from its own device ---
    for unit in [30u8, 31] {
        let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(unit))
            .await
            .expect("connect");
        let input = ctx
            .read_input_registers(8, 1)
            .await
            .expect("transport")
            .expect("read");
        assert_eq!(input, [2931], "unit {unit}");
    }

    // --- zenoh: both devices' tags by query ---
    let s = gateway_tests::zenoh_client(gw.zenoh_port.expect("zenoh port")).await;
    let mut got = std::collections::BTreeMap::new();
    let replies = s.get("gw/tpl/meters/*/temperature").await.expect("get");
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            let v: Value = serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON");
            got.insert(sample.key_expr().to_string(), v);
        }
    }
    assert_eq!(
        got["gw/tpl/meters/m30/temperature"]["value"].to_string(),
        "19.95",
        "{got:?}"
    );
    assert_eq!(
        got["gw/tpl/meters/m31/temperature"]["value"].to_string(),
        "293.1",
        "{got:?}"
    );
    assert_eq!(
        got["gw/tpl/meters/m31/temperature"]["description"], "raw kelvin",
        "{got:?}"
    );

    // --- GET /config: the devices and the template as written ---
    let text = client
        .get(format!("{base}/api/v1/config"))
        .header("Accept", "application/toml")
        .send()
        .await
        .expect("GET /config")
        .text()
        .await
        .expect("text");
    let doc: toml::Table = text.parse().expect("TOML");
    let devices = &doc["lines"]["meters"]["devices"];
    assert_eq!(devices["m30"]["template"].as_str(), Some("meter"), "{text}");
    assert!(devices["m30"].get("tags").is_none(), "{text}");
    assert_eq!(
        devices["m31"]["tags"].as_array().map(Vec::len),
        Some(1),
        "{text}"
    );
    assert!(
        doc["templates"]["meter_here"].get("tags").is_some(),
        "{text}"
    );
}
