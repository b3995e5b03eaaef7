//! The README's command examples, run as written against a demo, so that they cannot drift from
//! the gateway: every `mbpoll` and `curl` line of its code blocks (with the lines of shell around
//! them that feed them, such as `seq=$(mbpoll ...)`), and its zenoh Python examples. The examples
//! are read from README.md when the test runs; only the ports are rewritten (the README's 5020,
//! 8080 and 7447 become the demo's, which listens on free ports).
//!
//! What is checked: each command exits 0 (curl with `--fail-with-body`: an HTTP error fails it);
//! where the README says what a read gives (`-> 40 600 500 0` in the comment above it), mbpoll's
//! values are those; a followed stream (`?follow=true`) delivers frames until it is cut off.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use gateway_tests::{tool, venv_python, Gateway};

/// One command of a README code block, with the comment line just above it.
#[derive(Debug, Clone)]
struct Example {
    comment: Option<String>,
    command: String,
}

/// The README's indented code blocks, each as its lines without the 4-space indent (a line
/// ending with `\` joined with the next).
fn code_blocks(readme: &str) -> Vec<Vec<String>> {
    let mut blocks = Vec::new();
    let mut block: Vec<String> = Vec::new();
    let mut previous_blank = true;
    let mut in_block = false;
    for line in readme.lines() {
        let code = line.strip_prefix("    ");
        match code {
            Some(code) if in_block || previous_blank => {
                in_block = true;
                match block.last_mut() {
                    Some(last) if last.ends_with('\\') => {
                        last.pop();
                        last.push(' ');
                        last.push_str(code.trim_start());
                    }
                    _ => block.push(code.to_owned()),
                }
            }
            _ if line.trim().is_empty() && in_block => block.push(String::new()),
            _ => {
                if in_block {
                    while block.last().is_some_and(String::is_empty) {
                        block.pop();
                    }
                    blocks.push(std::mem::take(&mut block));
                }
                in_block = false;
            }
        }
        previous_blank = line.trim().is_empty();
    }
    if in_block {
        blocks.push(block);
    }
    blocks
}

/// The shell examples of a block: the `mbpoll` and `curl` commands and the assignments that run
/// one (`x=$(mbpoll ...)`).
fn shell_examples(block: &[String]) -> Vec<Example> {
    let mut out = Vec::new();
    let mut comment = None;
    for line in block {
        let line = line.trim();
        if let Some(c) = line.strip_prefix('#') {
            comment = Some(c.trim().to_owned());
            continue;
        }
        let runs = line.starts_with("mbpoll ")
            || line.starts_with("curl ")
            || line.contains("=$(mbpoll ")
            || line.contains("=$(curl ");
        if runs {
            out.push(Example {
                comment: comment.take(),
                command: line.to_owned(),
            });
        } else {
            comment = None;
        }
    }
    out
}

/// The numbers a comment says a read gives (`... -> 40 600 500 0`), if it says so.
fn expected_values(comment: &str) -> Option<Vec<i64>> {
    let (_, values) = comment.rsplit_once("->")?;
    values
        .split_whitespace()
        .map(|v| v.parse().ok())
        .collect::<Option<Vec<i64>>>()
        .filter(|v| !v.is_empty())
}

/// mbpoll's values (`[3102]: \t40`), in order.
fn mbpoll_values(out: &str) -> Vec<i64> {
    out.lines()
        .filter(|l| l.starts_with('['))
        .filter_map(|l| l.split_once(':'))
        .filter_map(|(_, v)| v.trim().parse().ok())
        .collect()
}

/// The README's ports replaced by the demo's.
fn rewrite(text: &str, gw: &Gateway) -> String {
    let http = gw.http.expect("the demo serves HTTP").to_string();
    let zenoh = format!(
        "tcp/127.0.0.1:{}",
        gw.zenoh_port.expect("the demo's zenoh port")
    );
    text.replace("-p 5020 ", &format!("-p {} ", gw.modbus_tcp.port()))
        .replace("tcp/127.0.0.1:7447", &zenoh)
        .replace("127.0.0.1:8080", &http)
}

/// Runs `script` with bash in `dir`; its output (stdout and stderr) and whether it exited 0.
fn bash(dir: &Path, script: &str, timeout: Duration) -> (bool, String) {
    let out = Command::new("timeout")
        .arg(timeout.as_secs().to_string())
        .args(["bash", "-c", script])
        .current_dir(dir)
        .stdin(Stdio::null())
        .output()
        .expect("bash runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

#[test]
fn the_readme_mbpoll_and_curl_examples_work_against_the_demo() {
    tool("mbpoll");
    tool("curl");
    let readme =
        std::fs::read_to_string(gateway_tests::repo_root().join("README.md")).expect("README.md");
    let blocks = code_blocks(&readme);
    let gw = Gateway::demo(&[]);
    let dir = gateway_tests::temp_dir("readme");
    // Give the demo's devices and telegram partners time to fill the image and the mailboxes
    // (the examples read values the first polls bring, and acknowledge a telegram).
    std::thread::sleep(Duration::from_secs(3));
    let mut ran = 0;
    let mut checked_values = 0;
    for block in &blocks {
        let examples = shell_examples(block);
        if examples.is_empty() {
            continue;
        }
        // One shell per block: a variable one line sets is there for the next.
        let mut script = String::new();
        for (i, example) in examples.iter().enumerate() {
            let mut command = rewrite(&example.command, &gw).replacen(
                "curl ",
                "curl --fail-with-body --max-time 30 ",
                1,
            );
            if command.contains("follow=true") {
                // A followed stream never ends: 3 s of it (curl's exit 28, the time limit).
                command = format!(
                    "{} > follow-{i}.out; rc=$?; cat follow-{i}.out; [ $rc = 28 ] && grep -q '^event: frame' follow-{i}.out",
                    command.replacen("--max-time 30", "--max-time 3", 1)
                );
            }
            script.push_str(&format!(
                "echo '@@start {i}'\n{command}\necho \"@@end {i} $?\"\n"
            ));
        }
        let (_, out) = bash(&dir, &script, Duration::from_secs(120));
        for (i, example) in examples.iter().enumerate() {
            let start = format!("@@start {i}\n");
            let section = out
                .split_once(&start)
                .map(|(_, rest)| rest)
                .unwrap_or_else(|| panic!("{}: did not run; output:\n{out}", example.command));
            let (output, status) = section
                .split_once(&format!("@@end {i} "))
                .unwrap_or_else(|| panic!("{}: did not end; output:\n{out}", example.command));
            let status = status.lines().next().unwrap_or("");
            assert_eq!(
                status, "0",
                "README example failed (exit {status}): {}\n{output}",
                example.command
            );
            if let Some(expected) = example.comment.as_deref().and_then(expected_values) {
                if example.command.starts_with("mbpoll ") {
                    assert_eq!(
                        mbpoll_values(output),
                        expected,
                        "README example: {}\n{output}",
                        example.command
                    );
                    checked_values += 1;
                }
            }
            ran += 1;
        }
    }
    // The README's blocks as they are today: the mbpoll reads and writes of the demo, the
    // mailbox's acknowledge, the health unit, the REST and the frame monitor examples.
    assert!(ran >= 20, "only {ran} README examples found");
    assert!(
        checked_values >= 3,
        "only {checked_values} examples with values"
    );
    let frames = std::fs::metadata(dir.join("drive.pcapng")).expect("the capture example's file");
    assert!(frames.len() > 100, "{frames:?}");
}

#[test]
fn the_readme_zenoh_python_examples_work_against_the_demo() {
    let python = venv_python("zenoh");
    let readme =
        std::fs::read_to_string(gateway_tests::repo_root().join("README.md")).expect("README.md");
    let blocks = code_blocks(&readme);
    // The session example (get, then a set), and the late joiner's advanced subscriber that uses
    // its session `s`, prints what history gives it while the script waits, and closes the
    // session (without that a script would never end).
    let session = blocks
        .iter()
        .find(|b| {
            b.first()
                .is_some_and(|l| l.starts_with("import zenoh, json"))
        })
        .expect("the README's zenoh session example");
    let late = blocks
        .iter()
        .find(|b| b.first().is_some_and(|l| l.starts_with("import zenoh.ext")))
        .expect("the README's advanced subscriber example");
    let gw = Gateway::demo(&[]);
    std::thread::sleep(Duration::from_secs(2));
    let script = format!(
        "{}\n{}\nprint('done')\n",
        session.join("\n"),
        late.join("\n")
    );
    let script = rewrite(&script, &gw);
    let out = Command::new("timeout")
        .args(["120", python.to_str().expect("utf-8 path"), "-c", &script])
        .stdin(Stdio::null())
        .output()
        .expect("python runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{script}\n{text}");
    // The get printed the drive's tags with their JSON; the late subscriber the KS vario's.
    assert!(text.contains("gw/demo/drive/atv71/ACC {"), "{text}");
    assert!(text.contains("\"quality\""), "{text}");
    assert!(text.contains("gw/demo/ksvario/"), "{text}");
    assert!(text.trim_end().ends_with("done"), "{text}");
}

#[test]
fn the_readme_code_blocks_are_read_as_written() {
    let readme = "text\n\n    # a -> 1 2\n    mbpoll -p 5020 x\n    curl -s -X PUT \\\n         -d '{}' y\n\nmore\n\n    import zenoh, json\n    for r in s:\n        print(r)\n";
    let blocks = code_blocks(readme);
    assert_eq!(blocks.len(), 2, "{blocks:?}");
    let examples = shell_examples(&blocks[0]);
    assert_eq!(examples.len(), 2);
    assert_eq!(examples[0].comment.as_deref(), Some("a -> 1 2"));
    assert_eq!(expected_values("a -> 1 2"), Some(vec![1, 2]));
    assert_eq!(examples[1].command, "curl -s -X PUT  -d '{}' y");
    assert_eq!(blocks[1][2], "    print(r)");
    assert_eq!(
        mbpoll_values("-- Polling\n[3102]: \t40\n[3103]: \t600\n"),
        vec![40, 600]
    );
}
