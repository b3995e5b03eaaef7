//! A server killed with SIGKILL in the middle of a series of PUTs leaves a configuration file
//! that loads: the last acknowledged version or the one in flight, never a broken one.
//!
//! The server runs in a child process: this test binary started again with an environment
//! variable that makes [`series_of_puts_child`] serve the API over the file until it is killed.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use gateway::api::{self, ApiState, Auth, Token};
use gateway::config::Baud;
use gateway::persist::ConfigStore;
use gateway::plant::Config;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::net::TcpListener;
use tokio::process::Command;

use super::backend::MemGateway;
use super::support::{test_config, TOKEN};

/// Set in the child: the configuration file it serves.
const CHILD_ENV: &str = "GATEWAY_API_TEST_CHILD_CONFIG";

/// Version `n` of the configuration: the gateway is named `v<n>`, the drive line's rate moves.
fn version(n: u64) -> Config {
    let mut c = test_config();
    c.gateway.name = format!("v{n}");
    let baud = if n % 2 == 0 { 19200 } else { 9600 };
    c.lines.get_mut("drive").unwrap().serial.baud = Baud::try_new(baud).unwrap();
    c
}

fn version_of(c: &Config) -> u64 {
    c.gateway
        .name
        .trim_start_matches('v')
        .parse()
        .unwrap_or_else(|_| panic!("not a version: {}", c.gateway.name))
}

/// Serves the API over the configuration file at `path` on 127.0.0.1 port 0.
async fn serve(path: PathBuf, announce: bool) -> (String, tokio::sync::oneshot::Sender<()>) {
    let store = ConfigStore::new(path);
    let config = store.load().expect("the configuration file loads at start");
    let gw = Arc::new(MemGateway::new(config, Vec::new()));
    let state =
        ApiState::new(gw, Auth::with_token(Token::new(TOKEN, "test").unwrap())).with_store(store);
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    if announce {
        println!("LISTENING {addr}");
    }
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    tokio::spawn(api::serve(listener, state, async {
        let _ = rx.await;
    }));
    (addr, tx)
}

/// PUTs versions `from..` one after the other; `sent` is the newest version sent, `acked` the
/// newest answered 200.
async fn put_series(addr: String, from: u64, sent: Arc<AtomicU64>, acked: Arc<AtomicU64>) {
    let http = reqwest::Client::new();
    for n in from.. {
        let body = serde_json::to_value(version(n)).unwrap();
        sent.store(n, Ordering::SeqCst);
        let r = http
            .put(format!("http://{addr}/api/v1/config"))
            .bearer_auth(TOKEN)
            .json(&body)
            .send()
            .await;
        match r {
            Ok(r) if r.status() == 200 => acked.store(n, Ordering::SeqCst),
            Ok(r) => panic!("PUT v{n}: {}", r.status()),
            Err(_) => return, // the server was killed
        }
    }
}

/// In the child (the variable set): serves until killed. As a plain test: a series of PUTs
/// in process, each persisted with the one before kept as `.prev`.
#[test]
fn series_of_puts_child() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    if let Some(path) = std::env::var_os(CHILD_ENV) {
        rt.block_on(async {
            let _keep = serve(PathBuf::from(path), true).await;
            std::future::pending::<()>().await;
        });
        return;
    }
    rt.block_on(async {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("gateway.toml");
        ConfigStore::new(&path).save(&version(0)).unwrap();
        let (addr, _stop) = serve(path.clone(), false).await;
        let http = reqwest::Client::new();
        for n in 1..=4 {
            let r = http
                .put(format!("http://{addr}/api/v1/config"))
                .bearer_auth(TOKEN)
                .json(&serde_json::to_value(version(n)).unwrap())
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), 200);
            let store = ConfigStore::new(&path);
            assert_eq!(version_of(&store.load().unwrap()), n);
            assert_eq!(version_of(&store.load_previous().unwrap()), n - 1);
        }
    });
}

async fn start_child(path: &Path) -> (tokio::process::Child, String) {
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "crash::series_of_puts_child",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, path)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let addr = tokio::time::timeout(Duration::from_secs(30), async {
        while let Some(line) = lines.next_line().await.unwrap() {
            // libtest writes "test <name> ... " before the test's own output, on the same line.
            if let Some((_, addr)) = line.split_once("LISTENING ") {
                return addr.trim().to_owned();
            }
        }
        panic!("the child ended without listening");
    })
    .await
    .expect("the child listens within 30 s");
    (child, addr)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_killed_during_a_series_of_puts_leaves_a_config_that_loads() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gateway.toml");
    let store = ConfigStore::new(&path);
    store.save(&version(0)).unwrap();
    let mut seed = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(7, |d| u64::from(d.subsec_nanos()) | 1);
    let mut on_disk = 0;
    let mut rounds_with_progress = 0;
    for round in 0..6 {
        let (mut child, addr) = start_child(&path).await;
        let sent = Arc::new(AtomicU64::new(on_disk));
        let acked = Arc::new(AtomicU64::new(on_disk));
        let series = tokio::spawn(put_series(addr, on_disk + 1, sent.clone(), acked.clone()));
        seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        tokio::time::sleep(Duration::from_millis(100 + (seed >> 33) % 200)).await;
        child.kill().await.unwrap(); // SIGKILL
        let _ = series.await;

        let (sent, acked) = (sent.load(Ordering::SeqCst), acked.load(Ordering::SeqCst));
        let loaded = store
            .load()
            .unwrap_or_else(|e| panic!("round {round}: the file does not load:\n{e}"));
        let v = version_of(&loaded);
        assert!(
            acked <= v && v <= sent,
            "round {round}: v{v} on disk, v{acked} acknowledged, v{sent} sent"
        );
        assert_eq!(
            loaded,
            version(v),
            "round {round}: the file is not version {v} as sent"
        );
        // A previous file exists once a PUT replaced the first file: a kill before the first
        // save of the first round leaves only version 0 (the machine may be slow to start).
        if v > 0 {
            store
                .load_previous()
                .unwrap_or_else(|e| panic!("round {round}: the previous file does not load:\n{e}"));
        }
        if acked > on_disk {
            rounds_with_progress += 1;
        }
        eprintln!("round {round}: v{v} on disk, acked v{acked}, sent v{sent}");
        on_disk = v;
    }
    assert!(
        rounds_with_progress >= 3,
        "PUTs were acknowledged in only {rounds_with_progress} rounds"
    );
}
