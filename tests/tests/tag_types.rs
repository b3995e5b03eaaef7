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
    let t = value(rest.get("temperature").await)
        .as_f64()
        .expect("number");
    assert!((t - 19.95).abs() < 1e-9, "{t}");
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
    assert_eq!(
        value(rest.get("power_factor").await),
        json!(f64::from(0.95f32))
    );

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
