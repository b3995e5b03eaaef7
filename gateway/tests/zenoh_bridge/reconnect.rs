//! Peers that leave and return, a client whose router is not there yet, a port in use.

use super::*;

/// Waits for the `gw/test` liveliness token to appear (`true`) or go (`false`).
async fn gateway_token(
    live: &mut tokio::sync::mpsc::UnboundedReceiver<zenoh::sample::Sample>,
    kind: SampleKind,
) {
    recv_until(live, Duration::from_secs(20), |s| {
        s.key_expr().as_str() == "gw/test" && s.kind() == kind
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn peers_leave_and_return_the_bridge_publishes_again() {
    // The bridge listens; peers come and go.
    let backend = TestBackend::new();
    let (bridge, handle, shutdown, port) = start_listening(backend).await;
    for round in 0..2 {
        let session = peer(&[endpoint(port)], &[]).await;
        let (_sub, mut rx) = subscribe(&session, "gw/test/**").await;
        publish_until_seen(&handle, &mut rx, 100 + round).await;
        session.close().await.unwrap();
        // Publishing into the void neither fails nor blocks.
        for seq in 0..50 {
            handle
                .publish_telegram("r3964", seq, SystemTime::now(), vec![0x02, 0x03])
                .unwrap();
        }
    }
    assert_eq!(handle.stats().drops(DropReason::PublishError), 0);
    shutdown.cancel();
    bridge.join().await;

    // The bridge connects to a peer that disappears and comes back on the same endpoint.
    let peer_port = free_port();
    let cfg = ZenohConfig {
        mode: Some(Mode::Peer),
        connect: Some(vec![endpoint(peer_port).try_into().unwrap()]),
        listen: Some(Vec::new()),
        multicast_scouting: Some(false),
        ..ZenohConfig::default()
    };
    let remote = peer(&[], &[endpoint(peer_port)]).await;
    let (bridge, handle, shutdown) = start(cfg, TestBackend::new()).await;
    let (_sub, mut rx) = subscribe(&remote, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 200).await;
    remote.close().await.unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let remote = peer(&[], &[endpoint(peer_port)]).await;
    let (_sub, mut rx) = subscribe(&remote, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 201).await;
    shutdown.cancel();
    bridge.join().await;
    remote.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_retries_until_its_router_appears() {
    let port = free_port();
    let cfg = ZenohConfig {
        mode: Some(Mode::Client),
        connect: Some(vec![endpoint(port).try_into().unwrap()]),
        listen: Some(Vec::new()),
        multicast_scouting: Some(false),
        ..ZenohConfig::default()
    };
    let (bridge, handle, shutdown) = start(cfg, TestBackend::new()).await;
    assert!(!handle.stats().session_open());
    // Queued before the session exists, published once it does.
    handle
        .publish_telegram("r3964", 1, SystemTime::now(), b"early".to_vec())
        .unwrap();
    tokio::time::sleep(Duration::from_millis(1500)).await;

    let remote = peer(&[], &[endpoint(port)]).await;
    let (live_tx, mut live) = tokio::sync::mpsc::unbounded_channel();
    let _live_sub = remote
        .liveliness()
        .declare_subscriber("gw/test/**")
        .history(true)
        .callback(move |s| {
            let _ = live_tx.send(s);
        })
        .await
        .unwrap();
    gateway_token(&mut live, SampleKind::Put).await;
    // The token can reach the router a moment before the bridge marks its session open.
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while !handle.stats().session_open() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "the session never opened"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let (_sub, mut rx) = subscribe(&remote, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 300).await;
    // The early telegram was published (to nobody yet) and counted.
    assert!(handle.stats().publications(PublicationKind::Telegram) >= 1);
    shutdown.cancel();
    bridge.join().await;
    gateway_token(&mut live, SampleKind::Delete).await;
    remote.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_peer_bridge_fails_to_start_on_a_busy_port() {
    let busy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = busy.local_addr().unwrap().port();
    let cfg = ZenohConfig::loopback_peer(&endpoint(port)).unwrap();
    let result = gateway::zenoh_bridge::Bridge::start(
        cfg,
        NAME,
        TestBackend::new(),
        tokio_util::sync::CancellationToken::new(),
    )
    .await;
    assert!(matches!(
        result,
        Err(gateway::zenoh_bridge::BridgeError::Open(_))
    ));
    drop(busy);
}
