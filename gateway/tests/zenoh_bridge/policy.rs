//! The publishing policy on a real session: a deadband holds small changes back, a heartbeat
//! publishes an unchanged value again, and every sample carries the time its poll read it.

use std::time::{Duration, Instant, SystemTime};

use gateway::zenoh_bridge::{Deadband, TagPolicy, TagRule, ZenohConfig};
use serde_json::json;

use super::support::*;

/// The time a simulated poll read the value (far from now: a publish time would not match).
fn polled_at(secs: u64) -> SystemTime {
    SystemTime::UNIX_EPOCH + Duration::from_secs(1_700_000_000 + secs)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn deadband_holds_back_small_changes_and_heartbeat_republishes() {
    let backend = TestBackend::new();
    let port = free_port();
    let mut cfg = ZenohConfig::loopback_peer(&endpoint(port)).unwrap();
    let heartbeat = Duration::from_millis(1500);
    cfg.publish.tags.push(TagRule {
        key: "drive/atv/cmd".into(),
        policy: TagPolicy {
            deadband: Deadband(10.0),
            deadband_percent: Deadband(0.0),
            heartbeat,
        },
    });
    let (_bridge, handle, _shutdown) = start(cfg, backend.clone()).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let (_sub, mut rx) = subscribe(&session, "gw/test/**").await;
    // Routes are in place once a tag without a policy gets through.
    publish_until_seen(&handle, &mut rx, 1).await;

    let cmd = "gw/test/drive/atv/cmd";
    // What a poll stores and the image announces: the backend holds it, the bridge is told.
    let poll = |v: i64, secs: u64| {
        let mut tv = value(json!(v), None);
        tv.timestamp = polled_at(secs);
        backend
            .tags
            .lock()
            .unwrap()
            .insert(("drive".into(), "atv".into(), "cmd".into()), tv.clone());
        handle.publish_tag("drive", "atv", "cmd", tv);
    };
    poll(100, 0);
    let first = recv_until(&mut rx, Duration::from_secs(10), |s| {
        s.key_expr().as_str() == cmd
    })
    .await;
    let body = json_of(&first);
    assert_eq!(body["value"], 100);
    assert_eq!(body["quality"], "good");
    assert_eq!(
        humantime::parse_rfc3339(body["timestamp"].as_str().unwrap()).unwrap(),
        polled_at(0),
        "the poll's time, not the publication's: {body}"
    );
    let published = Instant::now();

    // 105 is within 10 of 100: held back. 120 is not.
    poll(105, 1);
    poll(120, 2);
    let next = recv_until(&mut rx, Duration::from_secs(10), |s| {
        s.key_expr().as_str() == cmd
    })
    .await;
    let body = json_of(&next);
    assert_eq!(body["value"], 120, "105 was within the deadband: {body}");
    assert_eq!(
        humantime::parse_rfc3339(body["timestamp"].as_str().unwrap()).unwrap(),
        polled_at(2)
    );
    assert_eq!(handle.stats().within_deadband(), 1);
    assert!(
        published.elapsed() < heartbeat,
        "the steps took too long for the check"
    );
    let changed = Instant::now();

    // Nothing changes: the heartbeat publishes the current value again, with its poll's time,
    // about one heartbeat period after the last publication (the task looks every quarter).
    let again = recv_until(&mut rx, Duration::from_secs(10), |s| {
        s.key_expr().as_str() == cmd
    })
    .await;
    let waited = changed.elapsed();
    let body = json_of(&again);
    assert_eq!(body["value"], 120);
    assert_eq!(
        humantime::parse_rfc3339(body["timestamp"].as_str().unwrap()).unwrap(),
        polled_at(2)
    );
    assert!(waited >= heartbeat / 2, "heartbeat after {waited:?}");
    assert!(handle.stats().heartbeats() >= 1);
}
