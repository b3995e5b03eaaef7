//! The table reader behind [`super::parse`]: reads one TOML table key by key, converts each value
//! to its domain type, checks its range and records every problem with its path instead of
//! stopping at the first one.
//!
//! Each `Fields` remembers the keys it was asked for; [`Fields::finish`] reports every other key
//! of the table as unknown (the equivalent of serde's `deny_unknown_fields`, but for all unknown
//! keys at once and with their paths).

use std::fmt::Display;
use std::ops::RangeInclusive;
use std::str::FromStr;
use std::time::Duration;

use serde::de::DeserializeOwned;
use toml::Value;

use super::ConfigIssue;

/// Longest name accepted for the gateway, lines, devices, tags and poll groups.
pub(crate) const MAX_NAME_LEN: usize = 64;

/// Collects the issues of one parse.
#[derive(Debug, Default)]
pub(crate) struct Cx {
    pub(crate) issues: Vec<ConfigIssue>,
    /// Where a device's values came from when a template gave them: an issue found at a
    /// device's path is reported at the template's ([`Cx::relocate`]).
    pub(crate) relocations: Vec<Relocation>,
    /// The `[templates]` of the config being read, as written.
    pub(crate) templates: std::collections::BTreeMap<String, toml::Table>,
    /// The directories `NAME.toml` templates are looked for in, resolved.
    pub(crate) template_dirs: Vec<std::path::PathBuf>,
    /// Template files read in this parse (`None`: not found or not readable, reported once).
    pub(crate) template_files:
        std::collections::BTreeMap<String, Option<(toml::Table, std::path::PathBuf)>>,
    /// The directory relative `template_dirs` are resolved against.
    pub(crate) base_dir: Option<std::path::PathBuf>,
}

/// An issue at `from` (or below it) belongs at `to`, with `note` appended to its message.
#[derive(Debug, Clone)]
pub(crate) struct Relocation {
    pub(crate) from: String,
    pub(crate) to: String,
    pub(crate) note: String,
}

// === impl Cx ===

impl Cx {
    /// Moves every issue found at a device's value that a template gave to the template's path
    /// (naming the template and its file); issues then alike are reported once.
    pub(crate) fn relocate(&mut self) {
        if self.relocations.is_empty() {
            return;
        }
        let mut out: Vec<ConfigIssue> = Vec::with_capacity(self.issues.len());
        for mut issue in std::mem::take(&mut self.issues) {
            let best = self
                .relocations
                .iter()
                .filter(|r| {
                    issue.path.strip_prefix(&r.from).is_some_and(|rest| {
                        rest.is_empty()
                            || rest.starts_with('.')
                            || rest.starts_with('[') && !r.from.ends_with(']')
                    })
                })
                .max_by_key(|r| r.from.len());
            if let Some(r) = best {
                issue.path = format!("{}{}", r.to, &issue.path[r.from.len()..]);
                issue.message.push_str(&r.note);
            }
            if !out.contains(&issue) {
                out.push(issue);
            }
        }
        self.issues = out;
    }

    pub(crate) fn issue(&mut self, path: impl Into<String>, message: impl Into<String>) {
        self.issues.push(ConfigIssue {
            path: path.into(),
            message: message.into(),
        });
    }
}

/// `path.key`, or `key` at the root.
pub(crate) fn join(path: &str, key: &str) -> String {
    if path.is_empty() {
        key.to_owned()
    } else {
        format!("{path}.{key}")
    }
}

/// `path[i]`.
pub(crate) fn index(path: &str, i: usize) -> String {
    format!("{path}[{i}]")
}

/// "a string", "an integer", ... for messages.
pub(crate) fn kind(value: &Value) -> &'static str {
    match value {
        Value::String(_) => "a string",
        Value::Integer(_) => "an integer",
        Value::Float(_) => "a float",
        Value::Boolean(_) => "a boolean",
        Value::Datetime(_) => "a date-time",
        Value::Array(_) => "an array",
        Value::Table(_) => "a table",
    }
}

/// Shows a duration the way the config writes it: whole seconds as `2s`, else milliseconds.
pub(crate) fn show_duration(d: Duration) -> String {
    let ms = d.as_millis();
    if d.subsec_nanos() % 1_000_000 != 0 {
        format!("{}us", d.as_micros())
    } else if ms % 1000 == 0 && ms != 0 {
        format!("{}s", ms / 1000)
    } else {
        format!("{ms}ms")
    }
}

/// Checks a name used in metric labels and zenoh keys: 1..=64 of `[a-z0-9_-]`.
pub(crate) fn check_name(cx: &mut Cx, path: &str, name: &str) -> bool {
    let ok = !name.is_empty()
        && name.len() <= MAX_NAME_LEN
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-');
    if !ok {
        cx.issue(
            path,
            format!(
                "invalid name {name:?}: use 1 to {MAX_NAME_LEN} characters of a-z, 0-9, '_' and '-' \
                 (names appear in metric labels and zenoh keys)"
            ),
        );
    }
    ok
}

// === value-level readers (array elements and table fields) ===

pub(crate) fn string_value(cx: &mut Cx, value: &Value, path: &str) -> Option<String> {
    match value {
        Value::String(s) => Some(s.clone()),
        other => {
            cx.issue(path, format!("expected a string, found {}", kind(other)));
            None
        }
    }
}

pub(crate) fn int_value<T>(
    cx: &mut Cx,
    value: &Value,
    path: &str,
    range: RangeInclusive<T>,
    cite: &str,
) -> Option<T>
where
    T: TryFrom<i64> + Into<i64> + Copy + Display,
{
    let Value::Integer(n) = value else {
        cx.issue(path, format!("expected an integer, found {}", kind(value)));
        return None;
    };
    let (lo, hi) = ((*range.start()).into(), (*range.end()).into());
    match T::try_from(*n) {
        Ok(v) if (lo..=hi).contains(n) => Some(v),
        _ => {
            cx.issue(
                path,
                format!(
                    "must be between {} and {}{}, found {n}",
                    range.start(),
                    range.end(),
                    cited(cite)
                ),
            );
            None
        }
    }
}

pub(crate) fn duration_value(
    cx: &mut Cx,
    value: &Value,
    path: &str,
    range: RangeInclusive<Duration>,
    cite: &str,
) -> Option<Duration> {
    let Value::String(text) = value else {
        cx.issue(
            path,
            format!(
                "expected a duration such as \"500ms\" or \"2s\", found {}",
                kind(value)
            ),
        );
        return None;
    };
    let d = match humantime::parse_duration(text) {
        Ok(d) => d,
        Err(e) => {
            cx.issue(
                path,
                format!("invalid duration {text:?}: {e} (write e.g. \"500ms\" or \"2s\")"),
            );
            return None;
        }
    };
    if range.contains(&d) {
        Some(d)
    } else {
        cx.issue(
            path,
            format!(
                "must be between {} and {}{}, found {}",
                show_duration(*range.start()),
                show_duration(*range.end()),
                cited(cite),
                show_duration(d)
            ),
        );
        None
    }
}

pub(crate) fn parsed_value<T>(cx: &mut Cx, value: &Value, path: &str, what: &str) -> Option<T>
where
    T: FromStr,
    T::Err: Display,
{
    let text = string_value(cx, value, path)?;
    match text.parse() {
        Ok(v) => Some(v),
        Err(e) => {
            cx.issue(path, format!("invalid {what} {text:?}: {e}"));
            None
        }
    }
}

/// One of a fixed set of words, through the type's serde names (kebab-case).
pub(crate) fn choice_value<T: DeserializeOwned>(
    cx: &mut Cx,
    value: &Value,
    path: &str,
) -> Option<T> {
    if !value.is_str() {
        cx.issue(path, format!("expected a string, found {}", kind(value)));
        return None;
    }
    match value.clone().try_into::<T>() {
        Ok(v) => Some(v),
        Err(e) => {
            cx.issue(path, e.message().to_owned());
            None
        }
    }
}

fn cited(cite: &str) -> String {
    if cite.is_empty() {
        String::new()
    } else {
        format!(" ({cite})")
    }
}

/// Reads the keys of one table and reports the keys nobody asked for.
#[derive(Debug)]
pub(crate) struct Fields<'a> {
    table: &'a toml::Table,
    path: String,
    known: Vec<&'static str>,
}

// === impl Fields ===

impl<'a> Fields<'a> {
    pub(crate) fn new(table: &'a toml::Table, path: String) -> Self {
        Self {
            table,
            path,
            known: Vec::new(),
        }
    }

    /// `value` as a table, or an issue.
    pub(crate) fn of(cx: &mut Cx, value: &'a Value, path: String) -> Option<Self> {
        match value.as_table() {
            Some(table) => Some(Self::new(table, path)),
            None => {
                cx.issue(path, format!("expected a table, found {}", kind(value)));
                None
            }
        }
    }

    pub(crate) fn path(&self) -> &str {
        &self.path
    }

    /// The path of `key` in this table.
    pub(crate) fn at(&self, key: &str) -> String {
        join(&self.path, key)
    }

    /// The raw value of `key`, marking the key as known.
    pub(crate) fn raw(&mut self, key: &'static str) -> Option<&'a Value> {
        self.known.push(key);
        self.table.get(key)
    }

    pub(crate) fn string(&mut self, cx: &mut Cx, key: &'static str) -> Option<String> {
        let v = self.raw(key)?;
        string_value(cx, v, &self.at(key))
    }

    pub(crate) fn string_or(&mut self, cx: &mut Cx, key: &'static str, default: &str) -> String {
        self.string(cx, key).unwrap_or_else(|| default.to_owned())
    }

    pub(crate) fn required_string(&mut self, cx: &mut Cx, key: &'static str) -> Option<String> {
        if !self.table.contains_key(key) {
            self.known.push(key);
            cx.issue(self.at(key), "missing required key");
            return None;
        }
        self.string(cx, key)
    }

    pub(crate) fn bool(&mut self, cx: &mut Cx, key: &'static str) -> Option<bool> {
        match self.raw(key)? {
            Value::Boolean(b) => Some(*b),
            other => {
                cx.issue(
                    self.at(key),
                    format!("expected true or false, found {}", kind(other)),
                );
                None
            }
        }
    }

    pub(crate) fn bool_or(&mut self, cx: &mut Cx, key: &'static str, default: bool) -> bool {
        self.bool(cx, key).unwrap_or(default)
    }

    pub(crate) fn int<T>(
        &mut self,
        cx: &mut Cx,
        key: &'static str,
        range: RangeInclusive<T>,
        cite: &str,
    ) -> Option<T>
    where
        T: TryFrom<i64> + Into<i64> + Copy + Display,
    {
        let v = self.raw(key)?;
        int_value(cx, v, &self.at(key), range, cite)
    }

    pub(crate) fn int_or<T>(
        &mut self,
        cx: &mut Cx,
        key: &'static str,
        range: RangeInclusive<T>,
        default: T,
        cite: &str,
    ) -> T
    where
        T: TryFrom<i64> + Into<i64> + Copy + Display,
    {
        self.int(cx, key, range, cite).unwrap_or(default)
    }

    pub(crate) fn required_int<T>(
        &mut self,
        cx: &mut Cx,
        key: &'static str,
        range: RangeInclusive<T>,
        cite: &str,
    ) -> Option<T>
    where
        T: TryFrom<i64> + Into<i64> + Copy + Display,
    {
        if !self.table.contains_key(key) {
            self.known.push(key);
            cx.issue(self.at(key), "missing required key");
            return None;
        }
        self.int(cx, key, range, cite)
    }

    /// A float (integers are accepted too).
    pub(crate) fn float_or(&mut self, cx: &mut Cx, key: &'static str, default: f64) -> f64 {
        match self.raw(key) {
            None => default,
            Some(Value::Float(f)) if f.is_finite() => *f,
            #[allow(clippy::cast_precision_loss)] // config numbers are small
            Some(Value::Integer(n)) => *n as f64,
            Some(other) => {
                cx.issue(
                    self.at(key),
                    format!("expected a finite number, found {}", kind(other)),
                );
                default
            }
        }
    }

    pub(crate) fn duration(
        &mut self,
        cx: &mut Cx,
        key: &'static str,
        range: RangeInclusive<Duration>,
        cite: &str,
    ) -> Option<Duration> {
        let v = self.raw(key)?;
        duration_value(cx, v, &self.at(key), range, cite)
    }

    pub(crate) fn duration_or(
        &mut self,
        cx: &mut Cx,
        key: &'static str,
        range: RangeInclusive<Duration>,
        default: Duration,
        cite: &str,
    ) -> Duration {
        self.duration(cx, key, range, cite).unwrap_or(default)
    }

    pub(crate) fn parsed_or<T>(
        &mut self,
        cx: &mut Cx,
        key: &'static str,
        what: &str,
        default: T,
    ) -> T
    where
        T: FromStr,
        T::Err: Display,
    {
        match self.raw(key) {
            None => default,
            Some(v) => parsed_value(cx, v, &self.at(key), what).unwrap_or(default),
        }
    }

    pub(crate) fn choice<T: DeserializeOwned>(
        &mut self,
        cx: &mut Cx,
        key: &'static str,
    ) -> Option<T> {
        let v = self.raw(key)?;
        choice_value(cx, v, &self.at(key))
    }

    pub(crate) fn choice_or<T: DeserializeOwned>(
        &mut self,
        cx: &mut Cx,
        key: &'static str,
        default: T,
    ) -> T {
        self.choice(cx, key).unwrap_or(default)
    }

    /// The elements of an array with their paths; an issue if the value is not an array.
    pub(crate) fn array(&mut self, cx: &mut Cx, key: &'static str) -> Vec<(String, &'a Value)> {
        let Some(v) = self.raw(key) else {
            return Vec::new();
        };
        let path = self.at(key);
        match v.as_array() {
            Some(items) => items
                .iter()
                .enumerate()
                .map(|(i, item)| (index(&path, i), item))
                .collect(),
            None => {
                cx.issue(path, format!("expected an array, found {}", kind(v)));
                Vec::new()
            }
        }
    }

    /// The entries of a sub-table keyed by name, each with its path.
    pub(crate) fn named_tables(
        &mut self,
        cx: &mut Cx,
        key: &'static str,
    ) -> Vec<(String, String, &'a Value)> {
        let Some(v) = self.raw(key) else {
            return Vec::new();
        };
        let path = self.at(key);
        match v.as_table() {
            Some(t) => t
                .iter()
                .map(|(name, item)| (name.clone(), join(&path, name), item))
                .collect(),
            None => {
                cx.issue(path, format!("expected a table, found {}", kind(v)));
                Vec::new()
            }
        }
    }

    /// A sub-table, if present.
    pub(crate) fn table(&mut self, cx: &mut Cx, key: &'static str) -> Option<Self> {
        let v = self.raw(key)?;
        Fields::of(cx, v, self.at(key))
    }

    /// Whether `key` is present (without marking it known).
    pub(crate) fn has(&self, key: &str) -> bool {
        self.table.contains_key(key)
    }

    /// Reports every key nobody asked for.
    pub(crate) fn finish(self, cx: &mut Cx) {
        for key in self.table.keys() {
            if !self.known.contains(&key.as_str()) {
                let mut expected = self.known.clone();
                expected.sort_unstable();
                expected.dedup();
                cx.issue(
                    join(&self.path, key),
                    format!("unknown key (expected one of: {})", expected.join(", ")),
                );
            }
        }
    }
}

/// The TOML spelling of a unit-like enum value.
pub(crate) fn serde_name<T: serde::Serialize>(value: T) -> String {
    Value::try_from(value)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(text: &str) -> toml::Table {
        text.parse().expect("test toml")
    }

    #[test]
    fn int_range_and_type_errors_name_the_path() {
        let t = table("a = 11\nb = \"x\"\nc = 5");
        let mut cx = Cx::default();
        let mut f = Fields::new(&t, "lines.x".into());
        assert_eq!(f.int::<u8>(&mut cx, "a", 1..=10, "003 6.4.2.1"), None);
        assert_eq!(f.int::<u8>(&mut cx, "b", 1..=10, ""), None);
        assert_eq!(f.int::<u8>(&mut cx, "c", 1..=10, ""), Some(5));
        f.finish(&mut cx);
        assert_eq!(cx.issues.len(), 2);
        assert_eq!(cx.issues[0].path, "lines.x.a");
        assert_eq!(
            cx.issues[0].message,
            "must be between 1 and 10 (003 6.4.2.1), found 11"
        );
        assert_eq!(cx.issues[1].path, "lines.x.b");
        assert_eq!(cx.issues[1].message, "expected an integer, found a string");
    }

    #[test]
    fn unknown_keys_are_all_reported() {
        let t = table("a = 1\nzz = 2\nyy = 3");
        let mut cx = Cx::default();
        let mut f = Fields::new(&t, String::new());
        let _ = f.int::<u8>(&mut cx, "a", 0..=9, "");
        f.finish(&mut cx);
        let paths: Vec<_> = cx.issues.iter().map(|i| i.path.as_str()).collect();
        assert_eq!(paths, ["yy", "zz"]);
        assert_eq!(cx.issues[0].message, "unknown key (expected one of: a)");
    }

    #[test]
    fn durations_use_humantime_and_ranges() {
        let t = table("a = \"70s\"\nb = 5\nc = \"250ms\"\nd = \"2 fortnights\"");
        let mut cx = Cx::default();
        let mut f = Fields::new(&t, "p".into());
        let r = Duration::from_millis(5)..=Duration::from_millis(65_500);
        assert_eq!(f.duration(&mut cx, "a", r.clone(), "003 6.4.2.1"), None);
        assert_eq!(f.duration(&mut cx, "b", r.clone(), ""), None);
        assert_eq!(
            f.duration(&mut cx, "c", r.clone(), ""),
            Some(Duration::from_millis(250))
        );
        assert_eq!(f.duration(&mut cx, "d", r, ""), None);
        assert_eq!(
            cx.issues[0].message,
            "must be between 5ms and 65500ms (003 6.4.2.1), found 70s"
        );
        assert!(cx.issues[1].message.starts_with("expected a duration"));
        assert!(cx.issues[2]
            .message
            .starts_with("invalid duration \"2 fortnights\""));
    }

    #[test]
    fn names_are_restricted() {
        let mut cx = Cx::default();
        assert!(check_name(&mut cx, "p", "drive_1-a"));
        assert!(!check_name(&mut cx, "p", "Drive"));
        assert!(!check_name(&mut cx, "p", ""));
        assert!(!check_name(&mut cx, "p", "a/b"));
        assert!(!check_name(&mut cx, "p", &"a".repeat(65)));
        assert_eq!(cx.issues.len(), 4);
    }

    #[test]
    fn show_duration_forms() {
        assert_eq!(show_duration(Duration::from_secs(2)), "2s");
        assert_eq!(show_duration(Duration::from_millis(550)), "550ms");
        assert_eq!(show_duration(Duration::ZERO), "0ms");
        assert_eq!(show_duration(Duration::from_micros(500)), "500us");
    }
}
