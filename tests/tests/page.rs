//! The status page at `/` in a real browser: Debian's Chromium (`/usr/bin/chromium`) driven by
//! the pinned npm `playwright-core` of `tests/page/` (its lock file committed; Playwright never
//! downloads a browser here), against `gateway demo --token-file FILE` on free ports.
//!
//! The script `tests/page/page-test.js` checks, on the demo: the first look without JavaScript
//! (the server's snapshot lists the five lines); the five lines and the drive's tags; a value the
//! simulator changes (the drive's mains voltage) on screen within 2 s of the gateway reading it;
//! a drive frame in the frame monitor within 1 s of its first byte, its bytes in hex and ASCII by
//! keyboard, pause; a tag write refused visibly without the token (read-only, and the server's
//! 401 for a wrong one) and reaching the simulated drive with it (read back by a later poll); a
//! configuration edit with a mistake shown at its path with nothing changed (same ETag, the line
//! not restarted); a valid one-line edit refused (412) when the configuration changed since the
//! page loaded it and applied with `If-Match` after loading it again, restarting only that line;
//! the phone width; that no request leaves 127.0.0.1, no script error reaches
//! the console and at most 4 requests run at once. It saves a screenshot under
//! `target/page/` (CI artifact); with `PAGE_README_SCREENSHOT=1` also `docs/page.png`, the
//! README's picture.
//!
//! `.ci/test` installs Chromium and runs `npm ci` in `tests/page/`; a missing one fails this test
//! with that advice, never skips it.

use std::os::unix::fs::PermissionsExt;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use gateway_tests::{repo_root, temp_dir, Gateway};

/// Debian's Chromium.
const CHROMIUM: &str = "/usr/bin/chromium";
/// The longest the browser script may take (it needs about 20 s on an idle machine).
const SCRIPT_TIMEOUT: Duration = Duration::from_secs(180);

/// Panics with what installs `what` when `ok` is false.
fn need(ok: bool, what: &str) {
    assert!(
        ok,
        "{what} is missing: run the tests with `.ci/test`, which installs Debian's chromium and \
         runs `npm ci` in tests/page for the pinned playwright-core"
    );
}

#[test]
fn the_status_page_shows_the_demo_live_and_changes_it_with_the_rest_rules() {
    let node_runs = Command::new("node")
        .arg("--version")
        .stdin(Stdio::null())
        .output()
        .is_ok_and(|o| o.status.success());
    need(node_runs, "node (Debian package nodejs)");
    need(
        std::path::Path::new(CHROMIUM).exists(),
        "chromium (Debian package chromium)",
    );
    let page_dir = repo_root().join("tests/page");
    need(
        page_dir
            .join("node_modules/playwright-core/package.json")
            .exists(),
        "tests/page/node_modules/playwright-core",
    );

    let dir = temp_dir("page");
    let token = "page-test-token-0123456789abcdef";
    let token_file = dir.join("api-token");
    std::fs::write(&token_file, token).expect("write the token file");
    std::fs::set_permissions(&token_file, std::fs::Permissions::from_mode(0o600))
        .expect("token file mode");
    let gw = Gateway::demo(&["--token-file", token_file.to_str().expect("utf-8 path")]);
    let http = gw.http.expect("the demo serves HTTP");

    let shots = repo_root().join("target/page");
    let mut script = Command::new("node");
    script
        .arg(page_dir.join("page-test.js"))
        .current_dir(&page_dir)
        .env("GATEWAY_URL", format!("http://{http}"))
        .env("PAGE_TOKEN", token)
        .env("SCREENSHOT_DIR", &shots)
        .env("CHROMIUM", CHROMIUM)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    if std::env::var_os("PAGE_README_SCREENSHOT").is_some() {
        script.env("README_SCREENSHOT", repo_root().join("docs/page.png"));
    }
    let started = Instant::now();
    let mut child = script.spawn().expect("start node");
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for node") {
            break status;
        }
        if started.elapsed() > SCRIPT_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the browser script did not finish within {SCRIPT_TIMEOUT:?}");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let output = child.wait_with_output().expect("node output");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    println!("{stdout}{stderr}");
    assert!(
        status.success(),
        "the browser script failed after {:?}:\n{stdout}{stderr}\ngateway output:\n{}",
        started.elapsed(),
        gw.output()
    );
    assert!(stdout.contains("page-test: all checks passed"), "{stdout}");
    assert!(
        shots.join("status-page.png").exists(),
        "no screenshot in {}",
        shots.display()
    );
    // The REST side saw the page's write with the token: the audit names the token.
    assert!(
        gw.output().contains("token default"),
        "the audit does not name the page's token:\n{}",
        gw.output()
    );
    println!("browser script: {:?}", started.elapsed());
}
