//! A Modbus master line with metrics against the simulated Altivar 71 on a real pty pair: the
//! start-up event, traffic, polls, writes, on-demand reads and the device's exception are counted,
//! and every event the status counts is counted the same in `gateway_events_total`.

use std::time::Duration;

use gateway::app::Metrics;
use gateway::image::{ProcessImage, Table};
use gateway::metrics::encode_text;
use gateway::protocols::{
    spawn_modbus_master_line, AddrRange, DeviceSettings, LineSettings, PollGroup,
};
use gateway::serial::PortSettings;
use gateway::sim::{altivar::AltivarSim, serve_modbus};
use gateway::unit::UnitService;
use prometheus::Registry;
use proto_core::event::ids;
use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use proto_core::modbus::rtu::CharTiming;
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

/// The value of the sample `name{labels}` (labels in the encoder's order: sorted by name).
fn sample(text: &str, series: &str) -> Option<f64> {
    text.lines()
        .find_map(|line| line.strip_prefix(series)?.strip_prefix(' '))
        .and_then(|v| v.trim().parse().ok())
}

async fn eventually(registry: &Registry, what: &str, check: impl Fn(&str) -> bool) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        let text = encode_text(registry);
        if check(&text) {
            return;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for {what}:\n{text}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_master_line_counts_start_up_traffic_requests_and_device_state() {
    let (device_end, line_end) = SerialStream::pair().expect("pty pair");
    let path = line_end.name().expect("pty path");
    let shutdown = CancellationToken::new();
    let mut port = PortSettings::new(path, 19200);
    port.parity = gateway::serial::Parity::Even;
    let timing = CharTiming::new(port.baud, port.bits_per_char());
    tokio::spawn(serve_modbus(
        device_end,
        AltivarSim::new(2),
        timing,
        shutdown.clone(),
    ));

    let registry = Registry::new();
    let metrics = Metrics::register(&registry).expect("register");
    let mut settings = LineSettings::rtu("drive", port);
    settings.master.reply_timeout = Duration::from_millis(300);
    settings.metrics = Some(metrics.line().clone());
    let mut device = DeviceSettings::new("atv71", 2, 2);
    // SFr, tFr, HSP, LSP (002, the manual's FC03 example).
    device.groups = vec![PollGroup {
        period: Duration::from_millis(100),
        table: Table::HoldingRegisters,
        ranges: vec![AddrRange::new(3102, 4)],
    }];
    let line_token = shutdown.child_token();
    let line = spawn_modbus_master_line(
        settings,
        vec![device],
        ProcessImage::default(),
        line_token.clone(),
    );
    // Before the first answer the device counts as down.
    eventually(&registry, "the device up", |t| {
        sample(t, r#"gateway_device_up{device="atv71",line="drive"}"#) == Some(1.0)
    })
    .await;

    let unit = line.device_unit("atv71").expect("unit");
    // FC06 ACC = 13 (002's example), ETA is read-only (exception 04), CHCF read on demand.
    assert_eq!(
        unit.call(Request::WriteSingleRegister {
            address: 9001,
            value: 13
        })
        .await,
        Ok(Response::WriteSingleRegister {
            address: 9001,
            value: 13
        })
    );
    assert_eq!(
        unit.call(Request::WriteSingleRegister {
            address: 3201,
            value: 1
        })
        .await,
        Err(ExceptionCode::ServerDeviceFailure)
    );
    assert_eq!(
        unit.call(Request::ReadHoldingRegisters {
            address: 8401,
            quantity: 1
        })
        .await,
        Ok(Response::ReadHoldingRegisters(vec![3]))
    );

    let line_up = r#"gateway_line_up{line="drive",protocol="modbus-master-rtu"}"#;
    assert_eq!(sample(&encode_text(&registry), line_up), Some(1.0));
    // The line stops (after the request in flight) and the counters hold still.
    line_token.cancel();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    while line.status().port_open {
        assert!(
            tokio::time::Instant::now() < deadline,
            "the line did not stop"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let status = line.status();
    tokio::time::timeout(Duration::from_secs(5), line.join())
        .await
        .expect("line stops");
    let text = encode_text(&registry);
    let value = |series: &str| sample(&text, series).unwrap_or_else(|| panic!("{series}:\n{text}"));
    assert_eq!(value(line_up), 0.0);
    assert_eq!(
        value(
            r#"gateway_events_total{class="00",class_name="cp start-up",event="0003",line="drive"}"#
        ),
        1.0
    );
    assert_eq!(status.event_counts.get(&ids::PTP_PARAMS_ACCEPTED), Some(&1));
    // Every event the status counted, counted the same in the metrics (0E 64h for the 04).
    assert!(status.event_counts.len() >= 2, "{status:?}");
    for (id, count) in &status.event_counts {
        let series = format!(
            r#"gateway_events_total{{class="{:02X}",class_name="{}",event="{:02X}{:02X}",line="drive"}}"#,
            id.class,
            proto_core::event::class_name(id.class).unwrap_or("unknown"),
            id.class,
            id.number
        );
        assert_eq!(value(&series), *count as f64, "{series}");
    }
    let requests = |function: &str, result: &str| {
        value(&format!(
            r#"gateway_modbus_requests_total{{device="atv71",function="{function}",line="drive",result="{result}"}}"#
        ))
    };
    assert_eq!(requests("06", "ok"), 1.0);
    assert_eq!(requests("06", "exception_04"), 1.0);
    // The polls and the on-demand read.
    let reads = requests("03", "ok");
    assert!(reads >= 2.0);
    let polls = value(r#"gateway_poll_duration_seconds_count{device="atv71",line="drive"}"#);
    assert!(
        polls >= 1.0 && polls < reads,
        "{polls} polls of {reads} reads"
    );
    let tx = value(r#"gateway_telegrams_total{direction="tx",line="drive"}"#);
    let rx = value(r#"gateway_telegrams_total{direction="rx",line="drive"}"#);
    assert!(tx >= reads + 2.0 && rx >= reads + 2.0, "tx {tx} rx {rx}");
    // Every request here (FC03, FC06) is 8 bytes; the shortest answer, the exception, 5.
    assert_eq!(
        value(r#"gateway_bytes_total{direction="tx",line="drive"}"#),
        8.0 * tx
    );
    assert!(value(r#"gateway_bytes_total{direction="rx",line="drive"}"#) >= 5.0 * rx);
    assert!(
        value(r#"gateway_device_image_age_seconds{device="atv71",line="drive"}"#) < 5.0,
        "{text}"
    );

    shutdown.cancel();
}
