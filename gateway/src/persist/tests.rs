use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use super::*;

/// Set in the child process of [`a_writer_killed_at_any_moment_leaves_a_loadable_file`]: the
/// path of the file the child saves in a loop until it is killed.
const WRITER_ENV: &str = "GATEWAY_PERSIST_TEST_WRITER";

/// A valid configuration whose version shows in the gateway name and whose size varies, so that
/// a torn write would show as a parse error or a mismatch.
fn version(n: u64) -> String {
    let mut text = format!("[gateway]\nname = \"v{n}\"\ndiag_buffer_depth = 9\n");
    for i in 0..(n % 7) {
        text.push_str(&format!(
            "\n[lines.l{i}]\nport = \"/dev/ttyS{i}\"\nprotocol = \"modbus-master-rtu\"\nbaud = 9600\n"
        ));
    }
    text
}

/// The version number of a saved file (the `v<n>` gateway name); panics on a file that is not a
/// complete, valid version.
fn version_of(config: &Config) -> u64 {
    config
        .gateway
        .name
        .strip_prefix('v')
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("not a test version: {:?}", config.gateway.name))
}

#[test]
fn a_save_keeps_the_previous_version_and_leaves_no_temporary_file() {
    let dir = tempfile::tempdir().unwrap();
    let store = ConfigStore::new(dir.path().join("gateway.toml"));
    assert!(store.load().is_err(), "nothing saved yet");

    store.save_atomic(&version(1)).unwrap();
    assert_eq!(version_of(&store.load().unwrap()), 1);
    assert!(!store.previous_path().exists(), "no previous version yet");

    store.save_atomic(&version(2)).unwrap();
    store.save_atomic(&version(3)).unwrap();
    assert_eq!(version_of(&store.load().unwrap()), 3);
    assert_eq!(version_of(&store.load_previous().unwrap()), 2);

    let mut names: Vec<String> = fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["gateway.toml", "gateway.toml.prev"]);
}

#[test]
fn a_kept_text_shares_the_configuration_in_force_and_lets_a_replaced_one_go() {
    let text = format!("# the operator's comment\n{}", version(3));
    let first = Arc::new(crate::plant::parse(&text).unwrap());
    let shown = ConfigText::read(text.clone(), &first).expect("the text reads as it");
    assert!(std::ptr::eq(shown.config(), &*first), "shared, not a copy");
    let kept = shown.keep();
    drop(shown);

    // Still in force: the kept text is that configuration's, comment and all.
    let again = kept.reading_as(&first).expect("still in force");
    assert!(std::ptr::eq(again.config(), &*first));
    assert_eq!(again.text(), text);
    drop(again);

    // Replaced: the kept text does not hold the old configuration ...
    let renamed = text.replace("name = \"v3\"", "name = \"renamed\"");
    let second = Arc::new(crate::plant::parse(&renamed).unwrap());
    let gone = Arc::downgrade(&first);
    drop(first);
    assert!(
        gone.upgrade().is_none(),
        "the replaced configuration is freed"
    );
    assert!(kept.reading_as(&second).is_none());

    // ... and follows the one in force, the operator's comment kept.
    let followed = kept.following(&second);
    assert!(std::ptr::eq(followed.config(), &*second));
    assert_eq!(followed.text(), renamed);
}

#[test]
fn save_writes_a_config_that_loads_back_equal() {
    let dir = tempfile::tempdir().unwrap();
    let store = ConfigStore::new(dir.path().join("gateway.toml"));
    let demo = crate::plant::demo();
    store.save(&demo).unwrap();
    assert_eq!(store.load().unwrap(), demo);
}

#[cfg(unix)]
#[test]
fn a_save_keeps_the_file_permissions() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let store = ConfigStore::new(dir.path().join("gateway.toml"));
    store.save_atomic(&version(1)).unwrap();
    fs::set_permissions(store.path(), fs::Permissions::from_mode(0o640)).unwrap();
    store.save_atomic(&version(2)).unwrap();
    let mode = fs::metadata(store.path()).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o640);
}

#[test]
fn a_temporary_file_left_by_a_crash_is_overwritten_and_never_read() {
    let dir = tempfile::tempdir().unwrap();
    let store = ConfigStore::new(dir.path().join("gateway.toml"));
    store.save_atomic(&version(1)).unwrap();
    // What a crash during the first step leaves: a partial temporary file.
    fs::write(dir.path().join(".gateway.toml.tmp"), "[gateway]\nna").unwrap();
    assert_eq!(version_of(&store.load().unwrap()), 1);
    store.save_atomic(&version(2)).unwrap();
    assert_eq!(version_of(&store.load().unwrap()), 2);
    assert!(!dir.path().join(".gateway.toml.tmp").exists());
}

#[test]
fn a_save_into_a_missing_directory_fails_and_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let store = ConfigStore::new(dir.path().join("missing").join("gateway.toml"));
    let err = store.save_atomic(&version(1)).unwrap_err();
    assert!(
        matches!(
            err,
            PersistError::Io {
                step: "cannot create",
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains(".gateway.toml.tmp"), "{err}");
}

/// In the child process (the env var set): saves versions after the one on disk, forever, until
/// the parent kills it. Run as a normal test: a short series of saves that must each load.
#[test]
fn writer_child() {
    if let Some(path) = std::env::var_os(WRITER_ENV) {
        let store = ConfigStore::new(PathBuf::from(path));
        let mut n = store.load().map_or(0, |c| version_of(&c));
        loop {
            n += 1;
            store.save_atomic(&version(n)).expect("save");
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let store = ConfigStore::new(dir.path().join("gateway.toml"));
    for n in 1..=20 {
        store.save_atomic(&version(n)).unwrap();
        assert_eq!(version_of(&store.load().unwrap()), n);
    }
}

/// The test binary runs [`writer_child`] in a child process that is killed with SIGKILL after a
/// varying delay, again and again; after every kill the file holds a complete version, not older
/// than the one before the child started, and the previous version loads too.
#[test]
fn a_writer_killed_at_any_moment_leaves_a_loadable_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gateway.toml");
    let store = ConfigStore::new(&path);
    store.save_atomic(&version(0)).unwrap();
    let exe = std::env::current_exe().unwrap();
    // A small linear congruential sequence: varying delays without a random-number dependency.
    let mut seed = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(1, |d| d.subsec_nanos() as u64 | 1);
    let mut last = 0;
    let mut advanced = 0;
    let started = Instant::now();
    for round in 0..25 {
        let mut child = Command::new(&exe)
            .args([
                "--exact",
                "persist::tests::writer_child",
                "--test-threads=1",
            ])
            .env(WRITER_ENV, &path)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        std::thread::sleep(Duration::from_micros(20_000 + (seed >> 33) % 60_000));
        child.kill().unwrap(); // SIGKILL on unix
        child.wait().unwrap();

        let now = version_of(
            &store
                .load()
                .unwrap_or_else(|e| panic!("round {round}: the file does not load:\n{e}")),
        );
        assert!(
            now >= last,
            "round {round}: went back from v{last} to v{now}"
        );
        if now > last {
            advanced += 1;
            let prev = version_of(&store.load_previous().unwrap_or_else(|e| {
                panic!("round {round}: the previous file does not load:\n{e}")
            }));
            // Killed between keeping the previous version and the rename, `.prev` is the
            // current file: older is never newer.
            assert!(
                prev <= now,
                "round {round}: previous v{prev}, current v{now}"
            );
        }
        last = now;
        if started.elapsed() > Duration::from_secs(60) {
            break;
        }
    }
    // The child must have written (and been killed mid-series) in most rounds, or the test
    // proved nothing.
    assert!(
        advanced >= 5,
        "the writer advanced in only {advanced} rounds"
    );
}

/// The kept text is packed: a large configuration's text costs a fraction of its size and reads
/// back byte for byte (comments included), and two texts compare as their texts do.
#[test]
fn a_kept_text_is_packed_and_reads_back_exactly() {
    let mut text = String::from("# the plant's meters\n[gateway]\nname = \"packed\"\n");
    for d in 1..=20u8 {
        text.push_str(&format!(
            "\n[lines.m.devices.d{d}]  # meter {d}\nprofile = \"generic\"\naddress = {d}\ntags = [\n"
        ));
        for t in 0..500u16 {
            text.push_str(&format!(
                "  {{ name = \"t{t}\", table = \"holding\", address = {t} }},\n"
            ));
        }
        text.push_str("]\n");
    }
    text.insert_str(
        text.find("\n[lines.m.devices.d1]").expect("a device"),
        "\n[lines.m]\nport = \"/dev/ttyS0\"\nprotocol = \"modbus-master-rtu\"\n",
    );
    let config = Arc::new(crate::plant::parse(&text).expect("the test's configuration reads"));
    let kept = ConfigText::read(text.clone(), &config).expect("the text reads as its config");
    assert_eq!(kept.text(), text);
    assert_eq!(kept.keep().text(), text);
    let packed = kept.text.0.len();
    assert!(
        packed * 4 < text.len(),
        "{packed} bytes packed for a text of {} bytes",
        text.len()
    );
    let other = ConfigText::read(text.replace("meter 7", "meter 8"), &config).expect("reads");
    assert_ne!(kept, other);
    assert_eq!(kept, ConfigText::read(text, &config).expect("reads"));
}
