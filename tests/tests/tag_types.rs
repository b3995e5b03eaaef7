//! End to end on the binary: the demo's meter (slave 30 on the KS vario's bus, unit id 30) holds
//! one tag of every type the gateway decodes. Each is read over Modbus TCP (its raw registers
//! checked against the encoding written out here), REST and zenoh, and each writable kind is
//! written back over REST and zenoh, the bit tag without losing its register's other bits.

use std::time::{Duration, Instant};

use gateway_tests::Gateway;
use serde_json::{json, Value};
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::prelude::Slave;

const METER_UNIT: u8 = 30;
const TAGS: &str = "/api/v1/lines/ksvario/devices/meter/tags";

/// The registers of `bytes` (most significant first) with the registers reversed and/or the
/// bytes of each swapped: the four byte orders, written out independently of the gateway.
fn registers(bytes: &[u8], reversed: bool, swapped: bool) -> Vec<u16> {
    let mut words: Vec<u16> = bytes
        .chunks(2)
        .map(|c| {
            let w = u16::from_be_bytes([c[0], c[1]]);
            if swapped {
                w.swap_bytes()
            } else {
                w
            }
        })
        .collect();
    if reversed {
        words.reverse();
    }
    words
}

struct Rest {
    base: String,
    client: reqwest::Client,
}

impl Rest {
    async fn get(&self, tag: &str) -> Value {
        let r = self
            .client
            .get(format!("{}{TAGS}/{tag}", self.base))
            .send()
            .await
            .expect("GET");
        assert_eq!(r.status(), 200, "GET {tag}");
        r.json().await.expect("JSON")
    }

    /// PUT `{"value": value}`: the status and the body.
    async fn put(&self, tag: &str, value: Value) -> (u16, Value) {
        let r = self
            .client
            .put(format!("{}{TAGS}/{tag}", self.base))
            .json(&json!({ "value": value }))
            .send()
            .await
            .expect("PUT");
        let status = r.status().as_u16();
        (status, r.json().await.unwrap_or(Value::Null))
    }
}

async fn holding(ctx: &mut Context, address: u16, count: u16) -> Vec<u16> {
    ctx.read_holding_registers(address, count)
        .await
        .expect("transport")
        .expect("read")
}

/// Puts `payload` on `<tag>/set` and returns the JSON result the gateway publishes.
async fn zenoh_set(s: &zenoh::Session, tag: &str, payload: &str) -> Value {
    let key = format!("gw/demo/ksvario/meter/{tag}/set");
    let result = s
        .declare_subscriber(format!("{key}/result"))
        .await
        .expect("subscribe");
    s.put(&key, payload.to_owned()).await.expect("put");
    let r = tokio::time::timeout(Duration::from_secs(20), result.recv_async())
        .await
        .expect("a result within 20 s")
        .expect("sample");
    serde_json::from_slice(&r.payload().to_bytes()).expect("JSON result")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_tag_type_reads_and_writes_over_modbus_tcp_rest_and_zenoh() {
    let gw = Gateway::demo(&[]);
    let rest = Rest {
        base: format!("http://{}", gw.http.expect("the demo serves HTTP")),
        client: reqwest::Client::builder()
            .no_proxy()
            .timeout(Duration::from_secs(60))
            .build()
            .expect("HTTP client"),
    };
    // The meter's poll group reads every tag once a second.
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let v = rest.get("power_factor").await;
        if v["quality"] == "good" {
            break;
        }
        assert!(Instant::now() < deadline, "the meter was never polled: {v}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }

    // --- Modbus TCP: the raw registers, in the device's byte orders ---
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(METER_UNIT))
        .await
        .expect("connect");
    let energy: u64 = 0xF0DE_BC9A_7856_3412;
    let input = ctx
        .read_input_registers(0, 9)
        .await
        .expect("transport")
        .expect("read");
    // DCBA: little endian.
    assert_eq!(input[0..4], registers(&energy.to_be_bytes(), true, true));
    assert_eq!(input[0], 0x1234, "the low byte 12h first");
    // ABCD: big endian.
    assert_eq!(
        input[4..8],
        registers(&12_345.678_901_234f64.to_be_bytes(), false, false)
    );
    assert_eq!(input[8], 2931);
    // CDAB (GHEFCDAB): registers reversed.
    assert_eq!(
        holding(&mut ctx, 10, 4).await,
        registers(&(-1_234_567_890_123i64).to_be_bytes(), true, false)
    );
    let serial = holding(&mut ctx, 20, 8).await;
    assert_eq!(serial[0], u16::from_be_bytes(*b"GW"));
    assert_eq!(holding(&mut ctx, 30, 2).await, [0xA5F1, 100]);
    assert_eq!(
        holding(&mut ctx, 40, 4).await,
        registers(&99.5f64.to_be_bytes(), true, true)
    );
    assert_eq!(
        holding(&mut ctx, 60, 2).await,
        registers(&0.95f32.to_be_bytes(), true, false)
    );

    // --- REST: every value decoded, whole numbers exact beyond 2^53 and i64::MAX ---
    let value = |v: Value| v["value"].clone();
    assert_eq!(value(rest.get("energy").await), json!(energy));
    assert_eq!(
        value(rest.get("energy").await).as_u64(),
        Some(17_356_517_385_562_371_090)
    );
    assert_eq!(value(rest.get("flow").await), json!(12_345.678_901_234f64));
    // value = raw x 0.1 - 273.15, exact: 19.95 (before: 19.950000000000045).
    assert_eq!(value(rest.get("temperature").await).to_string(), "19.95");
    assert_eq!(
        value(rest.get("correction").await),
        json!(-1_234_567_890_123i64)
    );
    assert_eq!(value(rest.get("serial").await), json!("GW-17-0042"));
    assert_eq!(value(rest.get("running").await), json!(true));
    assert_eq!(value(rest.get("relay").await), json!(false));
    assert_eq!(value(rest.get("setpoint").await), json!(30.0));
    assert_eq!(value(rest.get("limit").await), json!(99.5));
    assert_eq!(value(rest.get("preset").await), json!(1_000_000_000_000u64));
    // An f32 reads in its own shortest form (before: 0.949999988079071).
    assert_eq!(value(rest.get("power_factor").await).to_string(), "0.95");

    // --- zenoh: the same values by query ---
    let s = gateway_tests::zenoh_client(gw.zenoh_port.expect("zenoh port")).await;
    let mut got = std::collections::BTreeMap::new();
    let replies = s.get("gw/demo/ksvario/meter/*").await.expect("get");
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            let v: Value = serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON");
            got.insert(sample.key_expr().to_string(), v["value"].clone());
        }
    }
    let z = |tag: &str| got[&format!("gw/demo/ksvario/meter/{tag}")].clone();
    assert_eq!(z("energy").as_u64(), Some(energy), "{got:?}");
    assert_eq!(z("correction"), json!(-1_234_567_890_123i64));
    assert_eq!(z("serial"), json!("GW-17-0042"));
    assert_eq!(z("flow"), json!(12_345.678_901_234f64));
    assert_eq!(z("running"), json!(true));
    assert_eq!(z("relay"), json!(false));
    assert_eq!(z("setpoint"), json!(30.0));
    assert_eq!(z("preset"), json!(1_000_000_000_000u64));
    assert_eq!(z("temperature").to_string(), "19.95");
    assert_eq!(z("power_factor").to_string(), "0.95");

    // --- REST writes, checked in the device's registers ---
    let (status, body) = rest
        .put("correction", json!(-9_007_199_254_740_993i64))
        .await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(body["value"], json!(-9_007_199_254_740_993i64));
    assert_eq!(
        holding(&mut ctx, 10, 4).await,
        registers(&(-9_007_199_254_740_993i64).to_be_bytes(), true, false)
    );
    let (status, body) = rest.put("preset", json!(u64::MAX)).await;
    assert_eq!(
        (status, body["value"].as_u64()),
        (200, Some(u64::MAX)),
        "{body}"
    );
    assert_eq!(holding(&mut ctx, 50, 4).await, [0xFFFF; 4]);
    let (status, body) = rest.put("serial", json!("SN-REST")).await;
    assert_eq!((status, &body["value"]), (200, &json!("SN-REST")), "{body}");
    let mut padded = b"SN-REST".to_vec();
    padded.resize(16, 0);
    assert_eq!(
        holding(&mut ctx, 20, 8).await,
        registers(&padded, false, false)
    );
    let (status, body) = rest.put("setpoint", json!(35.5)).await;
    assert_eq!((status, &body["value"]), (200, &json!(35.5)), "{body}");
    assert_eq!(holding(&mut ctx, 31, 1).await, [111]);
    let (status, body) = rest.put("limit", json!(-0.125)).await;
    assert_eq!((status, &body["value"]), (200, &json!(-0.125)), "{body}");
    assert_eq!(
        holding(&mut ctx, 40, 4).await,
        registers(&(-0.125f64).to_be_bytes(), true, true)
    );
    let (status, body) = rest.put("power_factor", json!(0.5)).await;
    assert_eq!((status, &body["value"]), (200, &json!(0.5)), "{body}");
    assert_eq!(
        holding(&mut ctx, 60, 2).await,
        registers(&0.5f32.to_be_bytes(), true, false)
    );

    // The bit: the register changes behind the gateway's back (another writer), and setting
    // the bit keeps every other bit the device holds.
    ctx.write_single_register(30, 0x1234)
        .await
        .expect("transport")
        .expect("write");
    let (status, body) = rest.put("relay", json!(true)).await;
    assert_eq!((status, &body["value"]), (200, &json!(true)), "{body}");
    assert_eq!(holding(&mut ctx, 30, 1).await, [0x123C]);
    assert_eq!(value(rest.get("running").await), json!(false));

    // Refusals: between two steps, out of range, too long, read-only.
    let (status, body) = rest.put("setpoint", json!(30.25)).await;
    assert_eq!(status, 422, "{body}");
    assert!(body.to_string().contains("nearest: 30.0 or 30.5"), "{body}");
    let (status, body) = rest.put("preset", json!(-1)).await;
    assert_eq!(status, 422, "{body}");
    let (status, body) = rest.put("serial", json!("0123456789ABCDEFG")).await;
    assert_eq!(status, 422, "{body}");
    let (status, body) = rest.put("running", json!(true)).await;
    assert_eq!(status, 409, "{body}");
    assert_eq!(holding(&mut ctx, 31, 1).await, [111], "nothing written");

    // --- zenoh writes ---
    let r = zenoh_set(&s, "relay", "false").await;
    assert_eq!(r["ok"], json!(true), "{r}");
    assert_eq!(holding(&mut ctx, 30, 1).await, [0x1234]);
    let r = zenoh_set(&s, "serial", r#""SN-ZENOH""#).await;
    assert_eq!(r["ok"], json!(true), "{r}");
    assert_eq!(value(rest.get("serial").await), json!("SN-ZENOH"));
    let r = zenoh_set(&s, "preset", "18446744073709551614").await;
    assert_eq!(r["ok"], json!(true), "{r}");
    assert_eq!(
        holding(&mut ctx, 50, 4).await,
        [0xFFFE, 0xFFFF, 0xFFFF, 0xFFFF]
    );
    let r = zenoh_set(&s, "correction", "-42").await;
    assert_eq!(r["ok"], json!(true), "{r}");
    assert_eq!(value(rest.get("correction").await), json!(-42));
    let r = zenoh_set(&s, "limit", "1.5e300").await;
    assert_eq!(r["ok"], json!(true), "{r}");
    assert_eq!(value(rest.get("limit").await), json!(1.5e300));
    let r = zenoh_set(&s, "setpoint", "30.25").await;
    assert_eq!(r["ok"], json!(false), "{r}");
    assert!(
        r["error"]
            .as_str()
            .is_some_and(|e| e.ends_with("nearest: 30.0 or 30.5")),
        "{r}"
    );
    let r = zenoh_set(&s, "serial", "12").await;
    assert_eq!(r["ok"], json!(false), "a number for a string tag: {r}");
    assert_eq!(value(rest.get("serial").await), json!("SN-ZENOH"));
}

/// The tags of [`values_read_and_write_as_written`]: one of every number type with scale,
/// offset and decimals, on the meter simulator's registers.
const VALUE_TAGS: &str = r#"
tags = [
  { name = "u16", table = "input", address = 8, type = "u16", scale = 0.1, offset = -273.15 },
  { name = "u16_d2", table = "input", address = 8, type = "u16", scale = 0.1, offset = -273.15, decimals = 2 },
  { name = "u16_d1", table = "input", address = 8, type = "u16", scale = 0.1, offset = -273.15, decimals = 1 },
  { name = "i16", table = "holding", address = 31, type = "i16", scale = 0.5, offset = -20.0, writable = true },
  { name = "bit", table = "holding", address = 30, bit = 0, decimals = 2 },
  { name = "u32", table = "holding", address = 70, type = "u32", scale = 0.01, decimals = 2, writable = true },
  { name = "i32", table = "holding", address = 72, type = "i32", scale = 0.1, offset = -273.15, writable = true },
  { name = "u64", table = "holding", address = 74, type = "u64", scale = 0.01, decimals = 2, writable = true },
  { name = "i64", table = "holding", address = 78, type = "i64", scale = 0.1, writable = true },
  { name = "f32", table = "holding", address = 82, type = "f32", writable = true },
  { name = "f32_scaled", table = "holding", address = 84, type = "f32", scale = 0.5, offset = -20.0, decimals = 1, writable = true },
  { name = "f64", table = "holding", address = 86, type = "f64", scale = 0.1, offset = -273.15, writable = true },
  { name = "fix", table = "holding", address = 90, type = "u16", scale = 0.1, decimals = 1, writable = true },
]
"#;

/// Values as written, end to end on the binary and `gateway sim --device meter`: value = raw x
/// scale + offset on the decimals as written, `decimals` only rounds. Every number type reads
/// the exact decimal over REST (one tag, the tag list) and zenoh, and writes round-trip without
/// float noise over both.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn values_read_and_write_as_written() {
    let dir = gateway_tests::temp_dir("values_as_written");
    let link = gateway_tests::SocatLink::new(&dir, "meter");
    let _meter = gateway_tests::device_sim("meter", &link.b);
    let config = |zenoh_port: u16| {
        format!(
            r#"
[gateway]
name = "values"

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
insecure_allow_unauthenticated_changes = true

[zenoh]
mode = "peer"
listen = ["tcp/127.0.0.1:{zenoh_port}"]
connect = []
multicast_scouting = false
writes = true

[lines.meters]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"

[lines.meters.devices.meter]
profile = "generic"
address = 30
unit_id = 30
{VALUE_TAGS}
[[lines.meters.devices.meter.poll]]
name = "all"
period = "200ms"
tags = ["u16", "u16_d2", "u16_d1", "i16", "bit", "u32", "i32", "u64", "i64", "f32", "f32_scaled", "f64", "fix"]
"#,
            port = link.a.display(),
        )
    };
    let gw = Gateway::run_on_free_zenoh_port(&dir.join("gateway.toml"), config);
    let base = format!("http://{}", gw.http.expect("HTTP"));
    let client = reqwest::Client::builder()
        .no_proxy()
        .timeout(Duration::from_secs(60))
        .build()
        .expect("HTTP client");
    let tag_url = |tag: &str| format!("{base}/api/v1/lines/meters/devices/meter/tags/{tag}");

    // The raw registers, written through to the simulated meter over Modbus TCP.
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(METER_UNIT))
        .await
        .expect("connect");
    let f32_words = |f: f32| registers(&f.to_be_bytes(), false, false);
    let mut raw: Vec<u16> = Vec::new();
    raw.extend(registers(&460u32.to_be_bytes(), false, false)); // 70: u32
    raw.extend(registers(&2931i32.to_be_bytes(), false, false)); // 72: i32
    raw.extend(registers(&12_345u64.to_be_bytes(), false, false)); // 74: u64
    raw.extend(registers(&(-7i64).to_be_bytes(), false, false)); // 78: i64
    raw.extend(f32_words(0.95)); // 82: f32
    raw.extend(f32_words(79.9)); // 84: f32 x 0.5 - 20
    raw.extend(registers(&2931f64.to_be_bytes(), false, false)); // 86: f64
    raw.push(46); // 90: fix point
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        match ctx.write_multiple_registers(70, &raw).await {
            Ok(Ok(())) => break,
            other => {
                assert!(
                    Instant::now() < deadline,
                    "the meter never took the write: {other:?}"
                );
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
        }
    }

    // The exact decimals, as JSON text (19.95, never 19.950000000000045).
    let expected = [
        ("u16", "19.95"),
        ("u16_d2", "19.95"),
        ("u16_d1", "20.0"),
        ("i16", "30.0"),
        ("bit", "true"),
        ("u32", "4.6"),
        ("i32", "19.95"),
        ("u64", "123.45"),
        ("i64", "-0.7"),
        ("f32", "0.95"),
        ("f32_scaled", "20.0"),
        ("f64", "19.95"),
        ("fix", "4.6"),
    ];
    let get = |tag: &str| {
        let url = tag_url(tag);
        let client = client.clone();
        async move {
            let r = client.get(url).send().await.expect("GET");
            assert_eq!(r.status(), 200);
            r.json::<Value>().await.expect("JSON")
        }
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let v = get("f64").await;
        if serde_json::to_string(&v["value"]).ok().as_deref() == Some("19.95") {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the meter's values never arrived: {v}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    for (tag, text) in expected {
        let v = get(tag).await;
        assert_eq!(v["quality"], "good", "{tag}: {v}");
        assert_eq!(v["value"].to_string(), text, "REST {tag}: {v}");
    }
    // The tag list shows the same numbers.
    let list: Value = client
        .get(format!("{base}/api/v1/tags?line=meters&device=meter"))
        .send()
        .await
        .expect("GET tags")
        .json()
        .await
        .expect("JSON");
    let listed: std::collections::BTreeMap<String, String> = list
        .as_array()
        .expect("a list")
        .iter()
        .map(|t| {
            (
                t["tag"].as_str().unwrap_or("").to_owned(),
                t["value"].to_string(),
            )
        })
        .collect();
    for (tag, text) in expected {
        assert_eq!(listed[tag], text, "the tag list's {tag}: {list}");
    }

    // zenoh: the same JSON numbers by query.
    let s = gateway_tests::zenoh_client(gw.zenoh_port.expect("zenoh port")).await;
    let query = |key: String| {
        let s = s.clone();
        async move {
            let mut got = std::collections::BTreeMap::new();
            let replies = s.get(key).await.expect("get");
            while let Ok(reply) = replies.recv_async().await {
                if let Ok(sample) = reply.result() {
                    let v: Value =
                        serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON");
                    let key = sample.key_expr().to_string();
                    let tag = key.rsplit('/').next().unwrap_or("").to_owned();
                    got.insert(tag, v["value"].to_string());
                }
            }
            got
        }
    };
    let got = query("gw/values/meters/meter/*".to_owned()).await;
    for (tag, text) in expected {
        assert_eq!(
            got.get(tag).map(String::as_str),
            Some(text),
            "zenoh {tag}: {got:?}"
        );
    }

    // REST writes echo the value written, and the registers hold raw = round((v - o) / s).
    let put = |tag: &str, value: Value| {
        let url = tag_url(tag);
        let client = client.clone();
        async move {
            let r = client
                .put(url)
                .json(&json!({ "value": value }))
                .send()
                .await
                .expect("PUT");
            let status = r.status().as_u16();
            (status, r.json::<Value>().await.unwrap_or(Value::Null))
        }
    };
    for (tag, value, address, words) in [
        ("fix", json!(4.6), 90, vec![46]),
        ("u32", json!(0.07), 70, vec![0, 7]),
        ("i32", json!(20.05), 72, vec![0, 2932]),
        ("i16", json!(30.5), 31, vec![101]),
        ("u64", json!(4.6), 74, vec![0, 0, 0, 460]),
        (
            "i64",
            json!(-4.6),
            78,
            registers(&(-46i64).to_be_bytes(), false, false),
        ),
        ("f32", json!(4.6), 82, f32_words(4.6)),
        (
            "f64",
            json!(4.6),
            86,
            registers(&2777.5f64.to_be_bytes(), false, false),
        ),
    ] {
        let (status, body) = put(tag, value.clone()).await;
        assert_eq!(status, 200, "PUT {tag} {value}: {body}");
        assert_eq!(
            body["value"].to_string(),
            value.to_string(),
            "the echo of {tag}: {body}"
        );
        let count = u16::try_from(words.len()).expect("a few registers");
        assert_eq!(
            holding(&mut ctx, address, count).await,
            words,
            "{tag} = {value}"
        );
    }
    // Between two steps: refused with the nearest values as the tag shows them.
    let (status, body) = put("i32", json!(19.97)).await;
    assert_eq!(status, 422, "{body}");
    assert!(
        body.to_string().contains("nearest: 19.95 or 20.05"),
        "{body}"
    );

    // zenoh writes: the same conversion, read back by query without noise.
    for (tag, payload) in [
        ("fix", "0.7"),
        ("f32", "0.3"),
        ("u32", "19.99"),
        ("f64", "-0.1"),
    ] {
        let key = format!("gw/values/meters/meter/{tag}/set");
        let result = s
            .declare_subscriber(format!("{key}/result"))
            .await
            .expect("subscribe");
        let published = s
            .declare_subscriber(format!("gw/values/meters/meter/{tag}"))
            .await
            .expect("subscribe");
        s.put(&key, payload.to_owned()).await.expect("put");
        let r = tokio::time::timeout(Duration::from_secs(20), result.recv_async())
            .await
            .expect("a result within 20 s")
            .expect("sample");
        let r: Value = serde_json::from_slice(&r.payload().to_bytes()).expect("JSON result");
        assert_eq!(r["ok"], json!(true), "{tag}: {r}");
        // Published on change by the next poll, as written.
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            let sample = tokio::time::timeout_at(deadline.into(), published.recv_async())
                .await
                .unwrap_or_else(|_| panic!("no sample of {tag} = {payload} within 20 s"))
                .expect("sample");
            let v: Value = serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON");
            if serde_json::to_string(&v["value"]).ok().as_deref() == Some(payload) {
                break;
            }
        }
        let got = query(format!("gw/values/meters/meter/{tag}")).await;
        assert_eq!(
            got.get(tag).map(String::as_str),
            Some(payload),
            "zenoh {tag}: {got:?}"
        );
    }
    assert_eq!(holding(&mut ctx, 90, 1).await, [7]);
    assert_eq!(holding(&mut ctx, 82, 2).await, f32_words(0.3));
}
