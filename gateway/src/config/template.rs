//! Device templates: what thirty identical devices share, written once.
//!
//! `[templates.NAME]` holds what a device holds (`profile`, `tags`, `poll`, `limits`,
//! `scanner`, the back-off keys), everything but `address`, `unit_id` and `template`; a device
//! says `template = "NAME"`. The template is found first in the config's `[templates]`, then as
//! `NAME.toml` in the directories of `[gateway] template_dirs` (a relative directory is taken
//! from the directory of the configuration file), whose top level holds the same keys.
//!
//! The template and the device's own keys are merged as TOML before the device is read, so a
//! template is read by exactly the rules of a device and reaches the line as any device does
//! (its profile from the registry, its tags on top: the same `DeviceProfile`). The device's keys
//! add to or replace the template's: a tag by its name, a poll group by its name, a key of
//! `limits` or `scanner` by itself, any other key whole. Every problem in a value the template
//! gave is reported at the template's path (`templates.meter.tags[2].scale`) and names the
//! template's file ([`Cx::relocate`]).
//!
//! A device read from a template keeps the template's values as read (`template_base`), so that
//! it is written back as the template's name and its own keys only (see
//! `DeviceConfig`'s `Serialize`): `GET /config` shows it as the operator wrote it.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use toml::Value;

use super::device::DeviceConfig;
use super::reader::{check_name, join, kind, string_value, Cx, Relocation};

/// Keys a template may not hold: they belong to one device.
pub const DEVICE_ONLY_KEYS: [&str; 3] = ["address", "unit_id", "template"];

/// Arrays whose elements merge by their `name`.
const NAMED_LISTS: [&str; 2] = ["tags", "poll"];

/// Tables whose keys merge one by one.
const MERGED_TABLES: [&str; 2] = ["limits", "scanner"];

/// A template found for a device.
#[derive(Debug, Clone)]
struct Found {
    /// Its keys as written.
    table: toml::Table,
    /// Where its problems are reported: `templates.NAME`.
    path: String,
    /// The file it was read from, `None` for one of the config's `[templates]`.
    file: Option<PathBuf>,
}

/// Reads the config's `[templates]` (kept as written) and where template files are looked for.
pub(crate) fn read_templates(
    cx: &mut Cx,
    raw: Option<&Value>,
    dirs: &[PathBuf],
) -> std::collections::BTreeMap<String, toml::Table> {
    cx.template_dirs = dirs
        .iter()
        .map(|d| match &cx.base_dir {
            Some(base) if d.is_relative() => base.join(d),
            _ => d.clone(),
        })
        .collect();
    let mut templates = std::collections::BTreeMap::new();
    let Some(raw) = raw else {
        return templates;
    };
    let Some(table) = raw.as_table() else {
        cx.issue(
            "templates",
            format!("expected a table of templates, found {}", kind(raw)),
        );
        return templates;
    };
    for (name, value) in table {
        let path = join("templates", name);
        check_name(cx, &path, name);
        let Some(t) = value.as_table() else {
            cx.issue(
                path,
                format!(
                    "expected a table (the keys of a device), found {}",
                    kind(value)
                ),
            );
            continue;
        };
        refuse_device_only_keys(cx, &path, t, "");
        templates.insert(name.clone(), t.clone());
    }
    cx.templates = templates.clone();
    templates
}

/// A template naming `address`, `unit_id` or `template` is refused: each device has its own
/// address, and templates do not nest.
fn refuse_device_only_keys(cx: &mut Cx, path: &str, table: &toml::Table, note: &str) {
    for key in DEVICE_ONLY_KEYS {
        if table.contains_key(key) {
            cx.issue(
                join(path, key),
                format!("a template holds what devices share; {key} belongs to each device{note}"),
            );
        }
    }
}

/// Reads one device table: as it is, or merged with the template it names.
pub(crate) fn read_device(cx: &mut Cx, path: &str, value: &Value) -> Option<DeviceConfig> {
    let Some((own, name_value)) = value
        .as_table()
        .and_then(|t| t.get("template").map(|n| (t, n)))
    else {
        return DeviceConfig::read(cx, path, value);
    };
    let at = join(path, "template");
    let mut own = own.clone();
    own.remove("template");
    let Some(name) = string_value(cx, name_value, &at) else {
        return DeviceConfig::read(cx, path, &Value::Table(own));
    };
    let found = find(cx, &name, &at)?;
    let (merged, relocations) = merge(path, &found, &own);
    cx.relocations.extend(relocations);
    let mut device = DeviceConfig::read(cx, path, &Value::Table(merged))?;
    device.template = Some(name);
    device.template_base = base(&found).map(Arc::new);
    Some(device)
}

/// The template `name`: the config's, else `NAME.toml` in the first template directory that has
/// it. Not found, unreadable or not TOML: one issue (at `at`, or at the template for its file).
fn find(cx: &mut Cx, name: &str, at: &str) -> Option<Found> {
    let path = join("templates", name);
    if let Some(table) = cx.templates.get(name) {
        return Some(Found {
            table: table.clone(),
            path,
            file: None,
        });
    }
    if !check_name(&mut Cx::default(), at, name) {
        cx.issue(
            at,
            format!("{name:?} is not a template name ([a-z0-9_-], 1..64 characters)"),
        );
        return None;
    }
    if let Some(cached) = cx.template_files.get(name) {
        return cached.clone().map(|(table, file)| Found {
            table,
            path,
            file: Some(file),
        });
    }
    let file = cx
        .template_dirs
        .iter()
        .map(|d| d.join(format!("{name}.toml")))
        .find(|f| f.is_file());
    let Some(file) = file else {
        cx.issue(
            at,
            format!(
                "no template {name:?}: not in [templates] and no {name}.toml in [gateway] \
                 template_dirs {:?}",
                cx.template_dirs
            ),
        );
        cx.template_files.insert(name.to_owned(), None);
        return None;
    };
    let read = read_file(cx, &path, name, &file);
    cx.template_files
        .insert(name.to_owned(), read.clone().map(|t| (t, file.clone())));
    read.map(|table| Found {
        table,
        path,
        file: Some(file),
    })
}

/// A template file's table; an issue (naming the file) when it cannot be read or is not TOML.
fn read_file(cx: &mut Cx, path: &str, name: &str, file: &Path) -> Option<toml::Table> {
    let note = format!(" (template {name:?}, file {})", file.display());
    let text = match std::fs::read_to_string(file) {
        Ok(text) => text,
        Err(e) => {
            cx.issue(path, format!("cannot read the template file: {e}{note}"));
            return None;
        }
    };
    match text.parse::<toml::Table>() {
        Ok(table) => {
            refuse_device_only_keys(cx, path, &table, &note);
            Some(table)
        }
        Err(e) => {
            cx.issue(path, format!("{}{note}", super::syntax_message(&text, &e)));
            None
        }
    }
}

/// The note an issue in a template's value gets.
fn note(found: &Found) -> String {
    let name = found.path.strip_prefix("templates.").unwrap_or(&found.path);
    match &found.file {
        Some(file) => format!(" (template {name:?}, file {})", file.display()),
        None => format!(" (template {name:?})"),
    }
}

/// The template's keys with the device's own added or in their place, and where each merged
/// value came from.
fn merge(path: &str, found: &Found, own: &toml::Table) -> (toml::Table, Vec<Relocation>) {
    let note = note(found);
    let mut relocations = Vec::new();
    let from_template = |relocations: &mut Vec<Relocation>, from: String, to: String| {
        relocations.push(Relocation {
            from,
            to,
            note: note.clone(),
        });
    };
    let mut merged = toml::Table::new();
    for (key, value) in &found.table {
        if DEVICE_ONLY_KEYS.contains(&key.as_str()) {
            continue;
        }
        let dev_at = join(path, key);
        let tpl_at = join(&found.path, key);
        match (own.get(key), value) {
            (None, _) => {
                from_template(&mut relocations, dev_at, tpl_at);
                merged.insert(key.clone(), value.clone());
            }
            (Some(Value::Array(mine)), Value::Array(theirs))
                if NAMED_LISTS.contains(&key.as_str()) =>
            {
                let mut list: Vec<(Value, Result<usize, usize>)> = theirs
                    .iter()
                    .cloned()
                    .enumerate()
                    .map(|(j, v)| (v, Err(j)))
                    .collect();
                for (k, item) in mine.iter().enumerate() {
                    let name = item.get("name").and_then(Value::as_str);
                    let slot = name.and_then(|n| {
                        list.iter().position(|(v, _)| {
                            v.get("name")
                                .and_then(Value::as_str)
                                .is_some_and(|m| m.eq_ignore_ascii_case(n))
                        })
                    });
                    match slot {
                        Some(i) => list[i] = (item.clone(), Ok(k)),
                        None => list.push((item.clone(), Ok(k))),
                    }
                }
                for (i, (_, origin)) in list.iter().enumerate() {
                    let at = format!("{dev_at}[{i}]");
                    match origin {
                        Err(j) => from_template(&mut relocations, at, format!("{tpl_at}[{j}]")),
                        Ok(k) if *k != i => relocations.push(Relocation {
                            from: at,
                            to: format!("{dev_at}[{k}]"),
                            note: String::new(),
                        }),
                        Ok(_) => {}
                    }
                }
                merged.insert(
                    key.clone(),
                    Value::Array(list.into_iter().map(|(v, _)| v).collect()),
                );
            }
            (Some(Value::Table(mine)), Value::Table(theirs))
                if MERGED_TABLES.contains(&key.as_str()) =>
            {
                let mut table = mine.clone();
                for (k, v) in theirs {
                    if !table.contains_key(k) {
                        from_template(&mut relocations, join(&dev_at, k), join(&tpl_at, k));
                        table.insert(k.clone(), v.clone());
                    }
                }
                merged.insert(key.clone(), Value::Table(table));
            }
            (Some(mine), _) => {
                merged.insert(key.clone(), mine.clone());
            }
        }
    }
    for (key, value) in own {
        if !merged.contains_key(key) {
            merged.insert(key.clone(), value.clone());
        }
    }
    (merged, relocations)
}

/// The template read as a device of its own (at a stand-in address), written out: what a device
/// of this template is written back against. `None` when it does not read alone (its device
/// gives what it lacks, or it has problems, reported through the device).
fn base(found: &Found) -> Option<toml::Table> {
    let mut alone = found.table.clone();
    alone.insert("address".to_owned(), Value::Integer(1));
    let mut scratch = Cx::default();
    let device = DeviceConfig::read(&mut scratch, "", &Value::Table(alone))?;
    if !scratch.issues.is_empty() {
        return None;
    }
    device.written_whole().ok()
}

#[cfg(test)]
mod tests {
    use crate::config;
    use crate::plant::Config;

    const TEMPLATE: &str = "profile = \"generic\"\n\
        tags = [\n\
          { name = \"energy\", table = \"input\", address = 0, type = \"u32\", unit = \"Wh\" },\n\
          { name = \"power\", table = \"input\", address = 2, scale = 0.1, unit = \"W\" },\n\
        ]\n\
        [[poll]]\nname = \"values\"\nperiod = \"1s\"\ntags = [\"energy\", \"power\"]\n";

    fn dir_with(name: &str, text: &str) -> tempfile::TempDir {
        let dir = tempfile::tempdir().expect("temp dir");
        std::fs::write(dir.path().join(format!("{name}.toml")), text).expect("write");
        dir
    }

    fn config(dir: &std::path::Path, devices: &str) -> String {
        format!(
            "[gateway]\ntemplate_dirs = [{:?}]\n\n\
             [templates.inline]\nprofile = \"generic\"\n\
             tags = [{{ name = \"level\", table = \"holding\", address = 5 }}]\n\n\
             [lines.m]\nport = \"/dev/ttyS0\"\nprotocol = \"modbus-master-rtu\"\n\n{devices}",
            dir.display()
        )
    }

    fn devices(c: &Config) -> &std::collections::BTreeMap<String, config::DeviceConfig> {
        c.lines["m"]
            .protocol
            .section()
            .devices()
            .expect("a master line")
    }

    #[test]
    fn a_device_takes_the_template_and_its_own_keys_replace_by_name() {
        let dir = dir_with("meter", TEMPLATE);
        let text = config(
            dir.path(),
            "[lines.m.devices.a]\ntemplate = \"meter\"\naddress = 1\n\n\
             [lines.m.devices.b]\ntemplate = \"meter\"\naddress = 2\n\
             tags = [\n\
               { name = \"power\", table = \"input\", address = 2, scale = 0.01, unit = \"kW\" },\n\
               { name = \"extra\", table = \"input\", address = 9 },\n\
             ]\n\n\
             [lines.m.devices.c]\ntemplate = \"inline\"\naddress = 3\n",
        );
        let c = crate::plant::parse(&text).unwrap_or_else(|e| panic!("{e}"));
        let d = devices(&c);
        let names =
            |n: &str| -> Vec<String> { d[n].tags.iter().map(|t| t.name.to_string()).collect() };
        assert_eq!(names("a"), ["energy", "power"]);
        assert_eq!(names("b"), ["energy", "power", "extra"]);
        assert_eq!((d["a"].tags[1].scale, d["a"].tags[1].unit()), (0.1, "W"));
        assert_eq!((d["b"].tags[1].scale, d["b"].tags[1].unit()), (0.01, "kW"));
        assert_eq!(d["a"].poll[0].name, "values");
        assert_eq!(names("c"), ["level"]);
        assert_eq!(d["a"].template.as_deref(), Some("meter"));

        // Written back as the operator wrote it: the template's name and the device's own keys.
        let written = toml::to_string(&c).expect("serialize");
        let table: toml::Table = written.parse().expect("TOML");
        let a = &table["lines"]["m"]["devices"]["a"];
        assert_eq!(a.get("tags"), None, "{written}");
        assert_eq!(a.get("profile"), None, "{written}");
        let b_tags = table["lines"]["m"]["devices"]["b"]["tags"]
            .as_array()
            .expect("own tags");
        assert_eq!(b_tags.len(), 2, "{written}");
        assert_eq!(crate::plant::parse(&written), Ok(c));
    }

    #[test]
    fn problems_name_the_template_and_its_file() {
        let bad = format!(
            "address = 4\n{}",
            TEMPLATE.replace("scale = 0.1", "scale = 0.0")
        );
        let dir = dir_with("meter", &bad);
        let file = dir.path().join("meter.toml");
        let text = config(
            dir.path(),
            "[lines.m.devices.a]\ntemplate = \"meter\"\naddress = 1\n\n\
             [lines.m.devices.b]\ntemplate = \"meter\"\naddress = 2\n\n\
             [lines.m.devices.c]\ntemplate = \"nowhere\"\naddress = 3\n",
        );
        let issues = crate::plant::parse(&text).expect_err("refused").issues;
        let note = format!("(template \"meter\", file {})", file.display());
        let scale = issues
            .iter()
            .filter(|i| i.path == "templates.meter.tags[1].scale")
            .collect::<Vec<_>>();
        assert_eq!(
            scale.len(),
            1,
            "reported once for both devices: {issues:#?}"
        );
        assert!(scale[0].message.ends_with(&note), "{issues:#?}");
        assert!(
            issues.iter().any(|i| i.path == "templates.meter.address"
                && i.message.contains("belongs to each device")
                && i.message.contains(&file.display().to_string())),
            "{issues:#?}"
        );
        assert!(
            issues.iter().any(|i| i.path == "lines.m.devices.c.template"
                && i.message.contains("no template \"nowhere\"")),
            "{issues:#?}"
        );
        // A file that is not TOML: its line and column, the template and the file.
        let broken = dir_with("meter", "profile = \n");
        let text = config(
            broken.path(),
            "[lines.m.devices.a]\ntemplate = \"meter\"\naddress = 1\n",
        );
        let issues = crate::plant::parse(&text).expect_err("refused").issues;
        assert_eq!(issues.len(), 1, "{issues:#?}");
        assert_eq!(issues[0].path, "templates.meter");
        assert!(
            issues[0].message.contains("line 1") && issues[0].message.contains("meter.toml"),
            "{issues:#?}"
        );
    }

    #[test]
    fn a_problem_in_the_device_stays_at_the_device() {
        let dir = dir_with("meter", TEMPLATE);
        let text = config(
            dir.path(),
            "[lines.m.devices.a]\ntemplate = \"meter\"\naddress = 1\n\
             tags = [{ name = \"other\", table = \"input\", address = 0, scale = 0.0 }]\n",
        );
        let issues = crate::plant::parse(&text).expect_err("refused").issues;
        assert!(
            issues
                .iter()
                .any(|i| i.path == "lines.m.devices.a.tags[0].scale"),
            "{issues:#?}"
        );
    }
}
