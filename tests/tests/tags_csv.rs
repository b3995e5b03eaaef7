//! End to end on the binary: `gateway tags export` and `gateway tags import`. A tag list goes out
//! as CSV, is edited as in a spreadsheet, comes back into the configuration file with the file's
//! comments kept, and goes out again as edited; a CSV with bad rows writes nothing and names each
//! problem's row and column.

use std::path::Path;
use std::process::{Command, Output};

const HEADER: &str =
    "name,table,address,type,byte_order,bit,registers,scale,offset,decimals,unit,writable,description";

const CONFIG: &str = r#"# The plant's meters (a comment the import keeps).
[gateway]
name = "csv"

[lines.m]
port = "/dev/ttyS0" # a port comment
protocol = "modbus-master-rtu"

# The energy meter on the first segment.
[lines.m.devices.meter]
profile = "generic"
address = 30

[[lines.m.devices.meter.tags]]
name = "energy"
table = "input"
address = 0
type = "u32"
unit = "Wh"

[[lines.m.devices.meter.tags]]
name = "temperature"
table = "input"
address = 8
scale = 0.1
offset = -273.15
unit = "degC"

[[lines.m.devices.meter.poll]]
name = "values"
period = "1s"
tags = ["energy", "temperature"]

# A template a device could name.
[templates.small]
profile = "generic"
tags = [
  { name = "level", table = "holding", address = 5 },
]
"#;

fn tags(args: &[&str]) -> Output {
    Command::new(gateway_tests::gateway_bin())
        .arg("tags")
        .args(args)
        .output()
        .expect("gateway tags")
}

fn export(config: &Path, owner: &[&str]) -> String {
    let mut args = vec!["export", "--config", config.to_str().expect("path")];
    args.extend_from_slice(owner);
    let out = tags(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("UTF-8")
}

fn import(config: &Path, owner: &[&str], csv: &Path) -> Output {
    let mut args = vec!["import", "--config", config.to_str().expect("path")];
    args.extend_from_slice(owner);
    args.push(csv.to_str().expect("path"));
    tags(&args)
}

const METER: [&str; 4] = ["--line", "m", "--device", "meter"];

#[test]
fn export_edit_import_export_keeps_the_file_and_its_comments() {
    let dir = gateway_tests::temp_dir("tags_csv_round_trip");
    let config = dir.join("gateway.toml");
    std::fs::write(&config, CONFIG).expect("write config");

    let csv = export(&config, &METER);
    assert_eq!(
        csv,
        format!(
            "{HEADER}\nenergy,input,0,u32,,,,,,,Wh,,\ntemperature,input,8,,,,,0.1,-273.15,,degC,,\n"
        )
    );

    // Export then import: the same configuration.
    let same = dir.join("same.csv");
    std::fs::write(&same, &csv).expect("write csv");
    let out = import(&config, &METER, &same);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let before: toml::Table = CONFIG.parse().expect("TOML");
    let after: toml::Table = std::fs::read_to_string(&config)
        .expect("read")
        .parse()
        .expect("TOML");
    assert_eq!(after, before);

    // Edited as in a spreadsheet: a scale changed, a tag with a description added.
    let edited = csv.replace("0.1,-273.15", "0.01,-273.15")
        + "relay,holding,30,bool,,3,,,,,,true,\"relay 3, the pump\"\n";
    let file = dir.join("edited.csv");
    std::fs::write(&file, &edited).expect("write csv");
    let out = import(&config, &METER, &file);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("3 tags"),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let text = std::fs::read_to_string(&config).expect("read");
    for comment in [
        "# The plant's meters (a comment the import keeps).",
        "# a port comment",
        "# The energy meter on the first segment.",
        "# A template a device could name.",
    ] {
        assert!(text.contains(comment), "{comment} lost:\n{text}");
    }
    assert_eq!(export(&config, &METER), edited);
    let (ok, report) = gateway_tests::check_config(&config);
    assert!(ok, "{report}");

    // A template's list the same way.
    let small = export(&config, &["--template", "small"]);
    assert_eq!(small, format!("{HEADER}\nlevel,holding,5,,,,,,,,,,\n"));
    let file = dir.join("small.csv");
    std::fs::write(
        &file,
        format!("{small}level2,holding,6,,,,,,,,,,second level\n"),
    )
    .expect("write csv");
    let out = import(&config, &["--template", "small"], &file);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        export(&config, &["--template", "small"]),
        format!("{small}level2,holding,6,,,,,,,,,,second level\n")
    );
    assert!(std::fs::read_to_string(&config)
        .expect("read")
        .contains("# A template a device could name."));
}

#[test]
fn a_csv_with_bad_rows_writes_nothing_and_names_row_and_column() {
    let dir = gateway_tests::temp_dir("tags_csv_bad_rows");
    let config = dir.join("gateway.toml");
    std::fs::write(&config, CONFIG).expect("write config");

    // A value that is no number: found while reading the CSV.
    let bad = dir.join("bad.csv");
    std::fs::write(
        &bad,
        format!(
            "{HEADER}\nenergy,input,0,u32,,,,,,,Wh,,\ntemperature,input,eight,,,,,0.1,,,degC,,\n"
        ),
    )
    .expect("write csv");
    let out = import(&config, &METER, &bad);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("row 3, column 3 (address): \"eight\" is not a whole number"),
        "{err}"
    );
    assert!(err.contains("nothing written"), "{err}");
    assert_eq!(std::fs::read_to_string(&config).expect("read"), CONFIG);

    // Values the configuration's rules refuse: found by the same check as `gateway check`.
    std::fs::write(
        &bad,
        format!(
            "{HEADER}\nenergy,input,0,u32,,,,0,,,Wh,,\ntemperature,input,8,u16,,,,,,,degC,,\n\
             energy,coil,1,,,,,,,,,,\n"
        ),
    )
    .expect("write csv");
    let out = import(&config, &METER, &bad);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("row 2, column 8 (scale): scale 0 makes every raw value 0"),
        "{err}"
    );
    assert!(err.contains("row 4, column 1 (name)"), "{err}");
    assert_eq!(std::fs::read_to_string(&config).expect("read"), CONFIG);
    assert!(!dir.join("gateway.toml.prev").exists(), "nothing was saved");

    // A wrong header.
    std::fs::write(&bad, "name,table,address\nenergy,input,0\n").expect("write csv");
    let out = import(&config, &METER, &bad);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("row 1: the header must be exactly"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(std::fs::read_to_string(&config).expect("read"), CONFIG);
}

/// Cells a spreadsheet would run as formulas (OWASP "CSV Injection"): export writes each text cell
/// that starts with `=`, `+`, `-`, `@`, a tab or a carriage return after a `'` and in quotes, a
/// negative number stays a number, and import gives the texts back as they were.
#[test]
fn formula_cells_are_escaped_on_export_and_read_back_on_import() {
    let dir = gateway_tests::temp_dir("tags_csv_formulas");
    let config = dir.join("gateway.toml");
    let texts = [
        "=HYPERLINK(\"http://evil.example/x\",\"click\")",
        "+cmd|' /C calc'!A0",
        "@SUM(A1:A9)",
        "-x",
        "\tleading tab",
        "\rleading return",
    ];
    let mut file = CONFIG.to_owned();
    for (i, text) in texts.iter().enumerate() {
        let escaped = text
            .replace('\\', "\\\\")
            .replace('"', "\\\"")
            .replace('\t', "\\t")
            .replace('\r', "\\r");
        file.push_str(&format!(
            "\n[[lines.m.devices.meter.tags]]\nname = \"f{i}\"\ntable = \"holding\"\n\
             address = {}\nunit = \"{escaped}\"\ndescription = \"{escaped}\"\noffset = -1.5\n",
            100 + i
        ));
    }
    // A tag name may start with '-' too.
    file.push_str(
        "\n[[lines.m.devices.meter.tags]]\nname = \"-dash\"\ntable = \"holding\"\naddress = 120\n",
    );
    std::fs::write(&config, &file).expect("write config");
    let (ok, report) = gateway_tests::check_config(&config);
    assert!(ok, "{report}");

    let csv = export(&config, &METER);
    for text in texts {
        let cell = format!("\"'{}\"", text.replace('"', "\"\""));
        assert!(
            csv.contains(&format!("{cell},,{cell}")),
            "unit and description of {text:?} escaped as {cell:?}:\n{csv}"
        );
    }
    assert!(csv.contains("\n\"'-dash\",holding,120,"), "{csv}");
    // The offset of the formula tags stays a number.
    assert!(csv.contains(",-1.5,"), "{csv}");
    assert!(!csv.contains("'-1.5"), "{csv}");

    // Import reads them back: the same configuration, byte for byte in its values.
    let same = dir.join("same.csv");
    std::fs::write(&same, &csv).expect("write csv");
    let out = import(&config, &METER, &same);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let before: toml::Table = file.parse().expect("TOML");
    let after: toml::Table = std::fs::read_to_string(&config)
        .expect("read")
        .parse()
        .expect("TOML");
    assert_eq!(after, before);
    assert_eq!(export(&config, &METER), csv);
}

/// A CSV over the stated bound (16 MiB) is refused before it is read, with a clear error, and the
/// configuration stays as it was.
#[test]
fn a_csv_over_the_bound_is_refused_before_it_is_read() {
    let dir = gateway_tests::temp_dir("tags_csv_too_large");
    let config = dir.join("gateway.toml");
    std::fs::write(&config, CONFIG).expect("write config");
    let big = dir.join("big.csv");
    let file = std::fs::File::create(&big).expect("create");
    // Sparse: the size says 16 MiB + 1 without writing them.
    file.set_len(16 * 1024 * 1024 + 1).expect("set_len");
    drop(file);
    let out = import(&config, &METER, &big);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("is too large: a tag list may have at most 16 MiB")
            && err.contains("16777217 bytes"),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(&config).expect("read"), CONFIG);

    // From standard input the same bound holds while reading.
    let mut child = Command::new(gateway_tests::gateway_bin())
        .args(["tags", "import", "--config"])
        .arg(&config)
        .args(METER)
        .arg("-")
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    let mut stdin = child.stdin.take().expect("stdin");
    let writer = std::thread::spawn(move || {
        use std::io::Write;
        if stdin.write_all(format!("{HEADER}\n").as_bytes()).is_err() {
            return;
        }
        let row = "t,input,0,,,,,,,,,,".to_owned() + &"d".repeat(80) + "\n";
        let mut text = String::new();
        while text.len() < 1024 * 1024 {
            text.push_str(&row);
        }
        // 17 MiB, or less if the gateway stops reading first.
        for _ in 0..17 {
            if stdin.write_all(text.as_bytes()).is_err() {
                break;
            }
        }
    });
    let out = child.wait_with_output().expect("wait");
    writer.join().expect("writer");
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("is too large"), "{err}");
    assert_eq!(std::fs::read_to_string(&config).expect("read"), CONFIG);
}
