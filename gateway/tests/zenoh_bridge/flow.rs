//! Order, drops and back-pressure: what reaches the fabric when, and that the producer never
//! waits.

use super::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thousand_telegrams_in_order_each_once() {
    const N: u64 = 1000;
    let backend = TestBackend::new();
    let (bridge, handle, shutdown, port) = start_listening(backend).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let (_sub, mut rx) = subscribe(&session, "gw/test/*/rx").await;
    let (_tags, mut tag_rx) = subscribe(&session, "gw/test/*/*/*").await;
    publish_until_seen(&handle, &mut tag_rx, 2).await;

    for seq in 0..N {
        let line = if seq % 3 == 0 { "ascii" } else { "r3964" };
        let bytes = format!("telegram {seq}").into_bytes();
        handle
            .publish_telegram(line, seq, SystemTime::now(), bytes)
            .unwrap();
    }
    let mut seen: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    for _ in 0..N {
        let s = tokio::time::timeout(LIMIT, rx.recv())
            .await
            .unwrap()
            .unwrap();
        let att: Value = serde_json::from_slice(&s.attachment().unwrap().to_bytes()).unwrap();
        let seq = att["seq"].as_u64().unwrap();
        assert_eq!(
            &*s.payload().to_bytes(),
            format!("telegram {seq}").as_bytes()
        );
        let line = s.key_expr().as_str().split('/').nth(2).unwrap().to_owned();
        seen.entry(line).or_default().push(seq);
    }
    let want_ascii: Vec<u64> = (0..N).filter(|s| s % 3 == 0).collect();
    let want_r3964: Vec<u64> = (0..N).filter(|s| s % 3 != 0).collect();
    assert_eq!(seen["ascii"], want_ascii);
    assert_eq!(seen["r3964"], want_r3964);
    // Nothing more arrives: each telegram was published once.
    assert!(tokio::time::timeout(Duration::from_millis(500), rx.recv())
        .await
        .is_err());
    assert_eq!(handle.stats().publications(PublicationKind::Telegram), N);
    assert_eq!(handle.stats().drops(DropReason::TelegramQueueFull), 0);

    shutdown.cancel();
    bridge.join().await;
    session.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_telegram_queue_drops_and_counts_the_new_ones() {
    // No session can publish before it is open: a client with nowhere to connect keeps
    // everything in the outbox.
    let port = free_port();
    let cfg = ZenohConfig {
        mode: Some(Mode::Client),
        connect: Some(vec![endpoint(port).try_into().unwrap()]),
        listen: Some(Vec::new()),
        multicast_scouting: Some(false),
        telegram_queue: 4.try_into().unwrap(),
        ..ZenohConfig::default()
    };
    let (bridge, handle, shutdown) = start(cfg, TestBackend::new()).await;
    for seq in 0..4 {
        assert!(handle
            .publish_telegram("r3964", seq, SystemTime::now(), vec![1])
            .is_ok());
    }
    assert_eq!(
        handle.publish_telegram("r3964", 4, SystemTime::now(), vec![1]),
        Err(DropReason::TelegramQueueFull)
    );
    assert_eq!(handle.stats().drops(DropReason::TelegramQueueFull), 1);
    assert_eq!(
        handle.publish_telegram("a/b", 5, SystemTime::now(), vec![1]),
        Err(DropReason::BadKey)
    );
    shutdown.cancel();
    bridge.join().await;
}

/// A gate a subscriber callback waits at while it is closed.
#[derive(Default)]
struct Gate {
    closed: std::sync::Mutex<bool>,
    changed: std::sync::Condvar,
}

impl Gate {
    fn set_closed(&self, closed: bool) {
        *self.closed.lock().unwrap() = closed;
        self.changed.notify_all();
    }

    fn pass(&self) {
        let mut closed = self.closed.lock().unwrap();
        while *closed {
            closed = self.changed.wait(closed).unwrap();
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stuck_subscriber_never_makes_the_producer_wait() {
    const N: u64 = 2000;
    let port = free_port();
    let mut cfg = ZenohConfig::loopback_peer(&endpoint(port)).unwrap();
    cfg.telegram_queue = 8.try_into().unwrap();
    let (bridge, handle, shutdown) = start(cfg, TestBackend::new()).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let gate = std::sync::Arc::new(Gate::default());
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let _stuck = {
        let gate = gate.clone();
        session
            .declare_subscriber("gw/test/**")
            .callback(move |s| {
                gate.pass();
                let _ = tx.send(s);
            })
            .await
            .unwrap()
    };
    publish_until_seen(&handle, &mut rx, 3).await;

    // The subscriber stops reading: zenoh's reader stalls, TCP pushes back, and the publisher
    // thread waits in its put (telegrams use CongestionControl::Block). 128 MB cannot fit in
    // the socket buffers and queues in between.
    gate.set_closed(true);
    let (mut queued, mut dropped) = (0u64, 0u64);
    for seq in 0..N {
        let bytes = vec![0x55; 64 * 1024];
        match handle.publish_telegram("r3964", seq, SystemTime::now(), bytes) {
            Ok(()) => queued += 1,
            Err(DropReason::TelegramQueueFull) => dropped += 1,
            Err(other) => panic!("unexpected drop reason {other:?}"),
        }
    }
    // The loop ended while the subscriber was still stuck: no call waited for the network.
    gate.set_closed(false);
    assert_eq!(queued + dropped, N);
    assert!(dropped > 0, "the queue never filled: nothing pushed back");
    assert_eq!(handle.stats().drops(DropReason::TelegramQueueFull), dropped);

    // What was queued arrives once the subscriber reads again: in order, each once.
    let mut last = None;
    for _ in 0..queued {
        let s = recv_until(&mut rx, Duration::from_secs(30), |s| {
            s.key_expr().as_str() == "gw/test/r3964/rx"
        })
        .await;
        let att: Value = serde_json::from_slice(&s.attachment().unwrap().to_bytes()).unwrap();
        let seq = att["seq"].as_u64().unwrap();
        assert!(last.is_none_or(|l| seq > l), "{seq} after {last:?}");
        last = Some(seq);
    }
    assert_eq!(
        handle.stats().publications(PublicationKind::Telegram),
        queued
    );

    shutdown.cancel();
    bridge.join().await;
    session.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_write_publishes_its_value_and_its_result() {
    // A write queues the tag's new value, then its result: two keys, published in whichever
    // order the publisher thread takes them. Neither may be lost, whatever the order. Writes
    // alternate between tags of two lines (two command workers).
    const N: i64 = 100;
    let backend = TestBackend::new();
    let (bridge, handle, shutdown, port) = start_listening(backend.clone()).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let (_sub, mut rx) = subscribe(&session, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 6).await;

    for i in 0..N {
        let key = if i % 2 == 0 {
            "gw/test/drive/atv/cmd"
        } else {
            "gw/test/ksvario/ks/w1"
        };
        let result_key = format!("{key}/set/result");
        session
            .put(format!("{key}/set"), i.to_string())
            .await
            .unwrap();
        let got = recv_keys(&mut rx, LIMIT, &[key, &result_key]).await;
        assert_eq!(json_of(&got[key])["value"], i, "write {i}");
        let r = json_of(&got[&result_key]);
        assert_eq!(
            (r["ok"].clone(), r["value"].clone()),
            (json!(true), json!(i))
        );
    }
    assert_eq!(backend.writes.lock().unwrap().len(), N as usize);
    assert_eq!(handle.stats().drops(DropReason::PublishError), 0);

    shutdown.cancel();
    bridge.join().await;
    session.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_payload_over_max_payload_is_refused_in_the_callback() {
    use gateway::zenoh_bridge::{CommandKind, CommandOutcome};
    use std::num::NonZeroUsize;

    let backend = TestBackend::new();
    let port = free_port();
    let mut cfg = ZenohConfig::loopback_peer(&endpoint(port)).unwrap();
    cfg.max_payload = NonZeroUsize::new(16).unwrap();
    let (bridge, handle, shutdown) = start(cfg, backend.clone()).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let (_sub, mut rx) = subscribe(&session, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 7).await;

    // 17 bytes (a valid JSON number): refused by its size, never written.
    let result_key = "gw/test/drive/atv/cmd/set/result";
    session
        .put("gw/test/drive/atv/cmd/set", "1".repeat(17))
        .await
        .unwrap();
    let got = recv_keys(&mut rx, LIMIT, &[result_key]).await;
    let r = json_of(&got[result_key]);
    assert_eq!(r["ok"], json!(false), "{r}");
    assert!(
        r["error"].as_str().unwrap().contains("max_payload = 16"),
        "{r}"
    );
    assert!(backend.writes.lock().unwrap().is_empty());
    assert_eq!(
        handle
            .stats()
            .commands(CommandKind::Set, CommandOutcome::Rejected),
        1
    );
    // 16 bytes are taken.
    session
        .put("gw/test/drive/atv/cmd/set", "1".repeat(16))
        .await
        .unwrap();
    let got = recv_keys(&mut rx, LIMIT, &[result_key]).await;
    assert_eq!(json_of(&got[result_key])["ok"], json!(true));
    assert_eq!(backend.writes.lock().unwrap().len(), 1);

    // A tag query carrying 17 bytes gets no reply; without a payload it does, and a tag
    // without a unit has "unit": "".
    let replies = session
        .get("gw/test/drive/atv/eta")
        .payload("x".repeat(17))
        .timeout(Duration::from_secs(2))
        .await
        .unwrap();
    assert!(replies.recv_async().await.is_err(), "no reply");
    assert_eq!(handle.stats().drops(DropReason::QueryTooLarge), 1);
    let eta = get_json(&session, "gw/test/drive/atv/eta").await;
    assert_eq!(eta["gw/test/drive/atv/eta"]["unit"], "", "{eta:?}");

    shutdown.cancel();
    bridge.join().await;
    session.close().await.unwrap();
}
