//! The configuration root: the [`Config`] of the whole gateway (its sections, its lines by name,
//! its templates), read from one TOML document, and the checks across the whole of it.
//!
//! It sits above the protocols: `config/` holds the sections every protocol shares and the
//! reader, `protocols/` the lines' table and each protocol's section, and this module the
//! document that holds them all.
//!
//! # How it reads
//!
//! [`parse`] reads the TOML into `toml::Table`s (a syntax error is one issue with line and
//! column): the tables outside `lines`, then each line's in turn, parsed from its own pieces of
//! the text and dropped once read (`read_text`: a whole document at once takes some 40 times its
//! text for a moment), and walks them table by table with one reader (`config::reader::Fields`):
//! each key is converted to its domain type (`SocketAddr`, `IpNet`, `Duration` through
//! humantime, enums, [`Baud`](crate::config::Baud), zenoh endpoints and key prefixes) and checked
//! against the manual's range; keys nobody asked for are refused with their path. A bad value is
//! reported and replaced by its default so that the walk goes on; then `validate::check` runs the
//! checks that span several keys. Every problem is a [`ConfigIssue`] with its path. This is what
//! serde's `deny_unknown_fields` would give, but with every problem of the file in one answer
//! instead of the first one, and with the flat line tables (`port`, `baud` and the protocol's
//! parameters side by side) that `#[serde(flatten)]` cannot combine with `deny_unknown_fields`.
//! Serializing uses serde (`toml::to_string(&config)`), and parsing the output gives the same
//! `Config` back; deserializing a [`Config`] with serde goes through the same reader.
//!
//! Checks that need another part of the gateway (whether the CP memory can serve a slave line
//! exactly) are the app's: it passes them as an [`ExtraCheck`] to [`load_with`], [`parse_with`] or
//! [`Config::from_table_with`], and their issues come in the same answer as the reader's.

pub(crate) mod check;
pub mod validate;

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Deserializer, Serialize};

use crate::config::reader::{self, check_name, Cx, Fields};
use crate::config::{syntax_message, template};
use crate::config::{
    ConfigErrors, ConfigIssue, CpMemoryConfig, GatewaySection, HttpConfig, ModbusTcpConfig,
    ZenohConfig, DEFAULT_CONFIG_DIR, DEFAULT_DIAG_BUFFER_DEPTH, DEFAULT_GATEWAY_NAME,
    DEFAULT_PORT_DIR, DEFAULT_STATE_DIR, MAX_DIAG_BUFFER_DEPTH,
};
use crate::protocols::LineConfig;

/// The embedded demo configuration (`gateway demo`).
const DEMO_TOML: &str = include_str!("demo.toml");

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Config {
    pub gateway: GatewaySection,
    pub modbus_tcp: ModbusTcpConfig,
    /// The CP memory served by `modbus-slave-rtu` lines and their unit ids.
    pub cp_memory: CpMemoryConfig,
    /// The zenoh session (`[zenoh]`); none: the gateway joins no zenoh fabric.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub zenoh: Option<ZenohConfig>,
    /// The REST API and `/metrics` (`[http]`): where they listen, the token, the limits.
    pub http: HttpConfig,
    /// Lines by name.
    pub lines: BTreeMap<String, LineConfig>,
    /// Device templates by name (`[templates.NAME]`), as written: a device naming one is read
    /// with the template's keys merged in (see the `template` module).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub templates: BTreeMap<String, toml::Table>,
}

impl Default for Config {
    /// What an empty file gives: no lines.
    fn default() -> Self {
        Self {
            gateway: GatewaySection::default(),
            modbus_tcp: ModbusTcpConfig::default(),
            cp_memory: CpMemoryConfig::new(),
            zenoh: None,
            http: HttpConfig::default(),
            lines: BTreeMap::new(),
            templates: BTreeMap::new(),
        }
    }
}

// === impl Config ===

impl Config {
    /// Runs every rule of [`parse`] on a config built or changed in code (e.g. a line replaced
    /// through the REST API): the config is written out and read back.
    pub fn check(&self) -> Result<(), ConfigErrors> {
        let table = toml::Table::try_from(self).map_err(|e| ConfigErrors {
            issues: vec![ConfigIssue {
                path: String::new(),
                message: format!("cannot serialize the config: {e}"),
            }],
        })?;
        Self::from_table(&table).map(drop)
    }

    /// The number of devices over all lines.
    pub fn device_count(&self) -> usize {
        self.lines.values().map(|l| l.devices().count()).sum()
    }

    /// A parsed `toml::Table` as a config.
    pub fn from_table(table: &toml::Table) -> Result<Self, ConfigErrors> {
        Self::from_table_with(table, &no_check)
    }

    /// A parsed `toml::Table` as a config, with `check`'s issues in the same answer.
    pub fn from_table_with(
        table: &toml::Table,
        check: ExtraCheck<'_>,
    ) -> Result<Self, ConfigErrors> {
        Self::from_table_in(table, None, check, BASE_DIR.get().cloned())
    }

    /// [`Self::from_table_with`], relative template directories taken from `base_dir`; the
    /// lines from `pieces` when given (`table` has none then).
    fn from_table_in(
        table: &toml::Table,
        pieces: Option<Pieces<'_>>,
        check: ExtraCheck<'_>,
        base_dir: Option<PathBuf>,
    ) -> Result<Self, ConfigErrors> {
        let mut cx = Cx {
            base_dir,
            ..Cx::default()
        };
        let config = read_root(&mut cx, table, pieces)?;
        validate::check(&mut cx, &config);
        let more = check(&config, &cx.issues);
        cx.issues.extend(more);
        cx.relocate();
        if cx.issues.is_empty() {
            Ok(config)
        } else {
            Err(ConfigErrors { issues: cx.issues })
        }
    }
}

/// Reads a config through [`parse`]'s rules, so that `toml::from_str::<Config>` and other serde
/// formats refuse unknown keys and report every problem too.
impl<'de> Deserialize<'de> for Config {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let table = toml::Table::deserialize(deserializer)?;
        Self::from_table(&table).map_err(serde::de::Error::custom)
    }
}

/// The `[gateway]` section.
fn read_gateway(cx: &mut Cx, mut f: Fields<'_>) -> GatewaySection {
    let name = f.string_or(cx, "name", DEFAULT_GATEWAY_NAME);
    check_name(cx, &f.at("name"), &name);
    let diag_buffer_depth = f.int_or(
        cx,
        "diag_buffer_depth",
        1..=MAX_DIAG_BUFFER_DEPTH,
        DEFAULT_DIAG_BUFFER_DEPTH,
        "003 7.3",
    );
    let mut dirs = |cx: &mut Cx, key, default: &str| {
        if !f.has(key) {
            let _ = f.raw(key);
            return vec![PathBuf::from(default)];
        }
        f.array(cx, key)
            .into_iter()
            .filter_map(|(path, v)| reader::string_value(cx, v, &path))
            .map(PathBuf::from)
            .collect()
    };
    let port_dirs = dirs(cx, "port_dirs", DEFAULT_PORT_DIR);
    let state_dirs = dirs(cx, "state_dirs", DEFAULT_STATE_DIR);
    let config_dirs = dirs(cx, "config_dirs", DEFAULT_CONFIG_DIR);
    let template_dirs = f
        .array(cx, "template_dirs")
        .into_iter()
        .filter_map(|(path, v)| reader::string_value(cx, v, &path))
        .map(PathBuf::from)
        .collect();
    f.finish(cx);
    GatewaySection {
        name,
        diag_buffer_depth,
        port_dirs,
        state_dirs,
        config_dirs,
        template_dirs,
    }
}

/// The root table read; a line's piece that does not parse is the document's syntax error.
fn read_root(
    cx: &mut Cx,
    table: &toml::Table,
    pieces: Option<Pieces<'_>>,
) -> Result<Config, ConfigErrors> {
    let mut root = Fields::new(table, String::new());
    let gateway = match root.table(cx, "gateway") {
        None => GatewaySection::default(),
        Some(f) => read_gateway(cx, f),
    };
    let modbus_tcp = match root.table(cx, "modbus_tcp") {
        None => ModbusTcpConfig::default(),
        Some(f) => ModbusTcpConfig::read(cx, f),
    };
    let cp_memory = match root.table(cx, "cp_memory") {
        None => CpMemoryConfig::new(),
        Some(f) => CpMemoryConfig::read(cx, f),
    };
    let zenoh = root.table(cx, "zenoh").map(|f| ZenohConfig::read(cx, f));
    let http = match root.table(cx, "http") {
        None => HttpConfig::default(),
        Some(f) => HttpConfig::read(cx, f),
    };
    let templates = template::read_templates(cx, root.raw("templates"), &gateway.template_dirs);
    let mut lines = BTreeMap::new();
    if let Some(Pieces { text, lines: cut }) = pieces {
        let _ = root.raw("lines");
        for (name, ranges) in cut {
            let piece: String = ranges.into_iter().map(|r| &text[r]).collect();
            // The whole text fails as its piece does, and says where in the file.
            let parsed = piece.parse::<toml::Table>().map_err(|e| {
                parse_whole(text)
                    .err()
                    .unwrap_or_else(|| syntax_errors(&piece, &e))
            })?;
            let path = reader::join("lines", &name);
            let value = parsed.get("lines").and_then(|l| l.get(&name));
            if let Some(line) = value.and_then(|v| LineConfig::read(cx, &name, &path, v)) {
                lines.insert(name, line);
            }
        }
    } else if table.get("lines").is_some_and(toml::Value::is_array) {
        let _ = root.raw("lines");
        cx.issue(
            "lines",
            "write each line as a table [lines.<name>], not as [[lines]]",
        );
    } else {
        for (name, path, value) in root.named_tables(cx, "lines") {
            if let Some(line) = LineConfig::read(cx, &name, &path, value) {
                lines.insert(name, line);
            }
        }
    }
    root.finish(cx);
    Ok(Config {
        gateway,
        modbus_tcp,
        cp_memory,
        zenoh,
        http,
        lines,
        templates,
    })
}

/// A configuration's text with each line's tables (`[lines.NAME]`, `[lines.NAME.devices.D]`,
/// `[[lines.NAME.devices.D.poll]]` ...) cut out, by line name: where they are in `text`.
struct Pieces<'t> {
    text: &'t str,
    lines: LineRanges,
}

/// Where each line's tables are in a text, by line name.
type LineRanges = BTreeMap<String, Vec<Range<usize>>>;

/// Reads a configuration's text. Parsing a whole TOML document takes some 40 times its size for
/// a moment (every token, every parser event, then the tables: 290 MiB for the 6 MB of 100 000
/// tags), so the text is first cut ([`cut`]) into the tables outside `lines` and each line's
/// tables, and each line is parsed, read and dropped in turn. That reads as the whole document
/// would: the pieces are the document's own statements, in its order, and no two of them can
/// define the same table. What does not cut or parse so (`[lines]` written as one table, a
/// syntax error) is parsed whole, as it always was, for the same answer and the same message.
fn read_text(
    text: &str,
    check: ExtraCheck<'_>,
    base_dir: Option<PathBuf>,
) -> Result<Config, ConfigErrors> {
    let cut = cut(text).and_then(|(rest, lines)| {
        let root: toml::Table = rest.parse().ok()?;
        (!root.contains_key("lines")).then_some((root, Pieces { text, lines }))
    });
    match cut {
        Some((root, pieces)) => Config::from_table_in(&root, Some(pieces), check, base_dir),
        None => Config::from_table_in(&parse_whole(text)?, None, check, base_dir),
    }
}

/// `text` parsed as one TOML table; a syntax error is the one issue.
fn parse_whole(text: &str) -> Result<toml::Table, ConfigErrors> {
    text.parse().map_err(|e| syntax_errors(text, &e))
}

fn syntax_errors(text: &str, e: &toml::de::Error) -> ConfigErrors {
    ConfigErrors {
        issues: vec![ConfigIssue {
            path: String::new(),
            message: syntax_message(text, e),
        }],
    }
}

/// `text` without the lines' tables, and where each line's tables are; `None` when the text does
/// not lex as TOML (its brackets do not pair) or a table header does not parse. A table header
/// is a `[` first on its line outside any value (the lexer keeps strings and comments whole).
fn cut(text: &str) -> Option<(String, LineRanges)> {
    use toml_parser::lexer::TokenKind;
    // Where each piece starts and the line it belongs to (none: the rest).
    let mut starts: Vec<(usize, Option<String>)> = vec![(0, None)];
    let (mut depth, mut line_start) = (0usize, true);
    for token in toml_parser::Source::new(text).lex() {
        match token.kind() {
            TokenKind::LeftSquareBracket if depth == 0 && line_start => {
                let at = token.span().start();
                let end = text[at..].find('\n').map_or(text.len(), |n| at + n + 1);
                let header: toml::Table = text[at..end].parse().ok()?;
                let line = match header.get("lines") {
                    Some(toml::Value::Table(t)) => t.keys().next().cloned(),
                    _ => None,
                };
                starts.push((at, line));
                depth = 1;
            }
            TokenKind::LeftSquareBracket | TokenKind::LeftCurlyBracket => depth += 1,
            TokenKind::RightSquareBracket | TokenKind::RightCurlyBracket => {
                depth = depth.checked_sub(1)?;
            }
            _ => {}
        }
        line_start = match token.kind() {
            TokenKind::Newline => true,
            TokenKind::Whitespace => line_start,
            _ => false,
        };
    }
    let mut rest = String::new();
    let mut lines = LineRanges::new();
    let ends: Vec<usize> = starts.iter().skip(1).map(|(at, _)| *at).collect();
    for ((start, line), end) in starts.into_iter().zip(ends.into_iter().chain([text.len()])) {
        match line {
            Some(name) => lines.entry(name).or_default().push(start..end),
            None => rest.push_str(&text[start..end]),
        }
    }
    Some((rest, lines))
}

/// Checks that need another part of the gateway (e.g. whether the CP memory can serve a slave
/// line exactly). The app passes them to [`parse_with`], [`load_with`] or
/// [`Config::from_table_with`]; they run on the config as read (a bad value replaced by its
/// default) after the reader's own rules, which found the issues given as second argument, and
/// their issues are reported with those in one answer.
pub type ExtraCheck<'a> = &'a dyn Fn(&Config, &[ConfigIssue]) -> Vec<ConfigIssue>;

/// The [`ExtraCheck`] that finds nothing.
pub fn no_check(_: &Config, _: &[ConfigIssue]) -> Vec<ConfigIssue> {
    Vec::new()
}

/// Parses and validates a configuration.
pub fn parse(text: &str) -> Result<Config, ConfigErrors> {
    parse_with(text, &no_check)
}

/// Parses and validates a configuration, with `check`'s issues in the same answer.
pub fn parse_with(text: &str, check: ExtraCheck<'_>) -> Result<Config, ConfigErrors> {
    read_text(text, check, BASE_DIR.get().cloned())
}

/// Parses and validates a configuration's text as if it were read from a file in `dir` (relative
/// `template_dirs` are taken from there), with `check`'s issues in the same answer: a file's new
/// text checked before it is written.
pub fn parse_in(text: &str, check: ExtraCheck<'_>, dir: &Path) -> Result<Config, ConfigErrors> {
    read_text(text, check, Some(dir.to_path_buf()))
}

/// Reads, parses and validates the configuration file at `path`.
pub fn load(path: &Path) -> Result<Config, ConfigErrors> {
    load_with(path, &no_check)
}

/// Reads, parses and validates the configuration file at `path`, with `check`'s issues in the
/// same answer. Relative `template_dirs` are taken from the file's directory; the first file a
/// process loads also gives that directory to the configurations it later reads from text (a
/// change over the REST API, the text `GET /config` shows).
pub fn load_with(path: &Path, check: ExtraCheck<'_>) -> Result<Config, ConfigErrors> {
    let text = std::fs::read_to_string(path).map_err(|e| ConfigErrors {
        issues: vec![ConfigIssue {
            path: String::new(),
            message: format!("cannot read {}: {e}", path.display()),
        }],
    })?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let _ = BASE_DIR.set(dir.clone());
    read_text(&text, check, Some(dir))
}

/// `dir` of `[gateway] template_dirs` as a configuration read from text takes it: a relative
/// directory from the directory of the first configuration file the process loaded.
pub fn template_dir_resolved(dir: &Path) -> PathBuf {
    match BASE_DIR.get() {
        Some(base) if dir.is_relative() => base.join(dir),
        _ => dir.to_path_buf(),
    }
}

/// The directory relative template directories are taken from when a configuration is read from
/// text: the directory of the first configuration file the process loaded.
static BASE_DIR: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();

/// The embedded demo configuration: lines `drive`, `ksvario`, `r3964`, `ascii` on `pty:` ports.
pub fn demo() -> Config {
    // The demo file is part of the binary and checked by tests; a failure is a build defect.
    parse(DEMO_TOML).unwrap_or_else(|e| panic!("embedded demo.toml is invalid:\n{e}"))
}

/// The text of the embedded demo configuration.
pub fn demo_toml() -> &'static str {
    DEMO_TOML
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the whole document reads as, parsed at once.
    fn whole(text: &str) -> Result<Config, ConfigErrors> {
        Config::from_table_in(&parse_whole(text)?, None, &no_check, None)
    }

    const LINE: &str = "port = \"/dev/ttyS1\"\nprotocol = \"modbus-master-rtu\"\n";
    const DEVICE: &str = "profile = \"generic\"\naddress = 2\n\
                          tags = [\n  { name = \"t0\", table = \"holding\", address = 0 },\n]\n";

    #[test]
    fn a_file_cut_into_its_lines_reads_as_the_whole_file() {
        let texts = [
            // Lines apart, a line's tables not together, comments and a header indented.
            format!(
                "[gateway]\nname = \"g\"\n[lines.b]\n{LINE}\n  [lines.a] # first\n\
                 port = \"/dev/ttyS2\"\nprotocol = \"3964r\"\n[http]\nlisten = \"127.0.0.1:0\"\n\
                 [lines.b.devices.d]\n{DEVICE}\
                 [[lines.b.devices.d.poll]]\nname = \"p\"\nperiod = \"1s\"\ntags = [\"t0\"]\n"
            ),
            // A quoted line name; a multi-line string whose line looks like a header.
            format!("[lines.\"q\"]\n{LINE}description = \"\"\"\n[lines.x]\n\"\"\"\n"),
            // Issues in two lines and at the root, in the order of the whole file.
            format!("unknown = 1\n[lines.b]\n{LINE}baud = 7\n[lines.a]\n{LINE}parity = \"odd?\"\n"),
            // A line's piece with a syntax error: the whole file's message, line and column.
            format!("[lines.a]\n{LINE}[lines.b]\n{LINE}baud = = 9\n"),
            // Two definitions of one line table.
            format!("[lines.a]\n{LINE}[gateway]\n[lines.a]\n{LINE}"),
            // Lines not cut: written in `[lines]` or inline, or as an array of tables.
            "[lines]\na = { port = \"/dev/ttyS1\", protocol = \"modbus-master-rtu\" }\n".to_owned(),
            format!("[[lines]]\n{LINE}"),
            "[lines.a]\nport = [\n".to_owned(),
            "]\n[lines.a]\n".to_owned(),
        ];
        for text in &texts {
            assert_eq!(read_text(text, &no_check, None), whole(text), "{text}");
        }
        let (rest, lines) = cut(&texts[0]).expect("cut");
        assert_eq!(
            rest,
            "[gateway]\nname = \"g\"\n[http]\nlisten = \"127.0.0.1:0\"\n"
        );
        assert_eq!(lines.keys().collect::<Vec<_>>(), ["a", "b"]);
        assert_eq!(lines["b"].len(), 3);
        assert_eq!(read_text(&texts[0], &no_check, None).err(), None);
        assert!(
            read_text(&texts[3], &no_check, None).is_err_and(|e| e.issues[0]
                .message
                .starts_with("TOML syntax error at line 7, column 8"))
        );
    }
}
