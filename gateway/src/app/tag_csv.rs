//! `gateway tags export` and `gateway tags import`: a device's (or a template's) tag list as CSV,
//! the spreadsheet a device vendor ships.
//!
//! The header is fixed: [`HEADER`]. Export writes the tags as the file gives them: a key the file
//! leaves out is an empty cell (its default applies), a value keeps the file's spelling. Import
//! replaces that tag list in the configuration file and keeps everything else of the file as it
//! is (comments, order, the other keys): an empty cell leaves its key out. Before anything is
//! written, the new file is read and checked as `gateway check` does (the reader's rules, the
//! CP memory, the start checks); every problem comes back with its CSV row and column, and the
//! file stays untouched. The file is replaced atomically ([`ConfigStore::save_atomic`]: a
//! temporary file renamed over it, the previous version kept as `.prev`). So export then import
//! gives the same configuration.
//!
//! CSV: RFC 4180 (fields separated by commas, a field with a comma, a quote or a line break in
//! double quotes, a quote in it doubled; lines end in LF or CRLF).

use std::path::{Path, PathBuf};

use toml_edit::{Array, ArrayOfTables, DocumentMut, InlineTable, Item, Table, Value};

use crate::config::{self, ConfigIssue};
use crate::persist::ConfigStore;

/// The columns, in order (a tag's keys; `type` is the data type).
pub const HEADER: [&str; 13] = [
    "name",
    "table",
    "address",
    "type",
    "byte_order",
    "bit",
    "registers",
    "scale",
    "offset",
    "decimals",
    "unit",
    "writable",
    "description",
];

/// Whose tag list: a device of a line, or a template of the configuration's `[templates]`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TagOwner {
    /// `lines.LINE.devices.DEVICE`.
    Device { line: String, device: String },
    /// `templates.NAME`.
    Template(String),
}

// === impl TagOwner ===

impl TagOwner {
    /// The owner's path in the configuration (`lines.a.devices.m`, `templates.meter`).
    pub fn path(&self) -> String {
        match self {
            Self::Device { line, device } => format!("lines.{line}.devices.{device}"),
            Self::Template(name) => format!("templates.{name}"),
        }
    }

    fn keys(&self) -> Vec<&str> {
        match self {
            Self::Device { line, device } => vec!["lines", line, "devices", device],
            Self::Template(name) => vec!["templates", name],
        }
    }
}

/// Why an export or an import did not happen.
#[derive(Debug, thiserror::Error)]
pub enum TagCsvError {
    /// The configuration file could not be read or is not TOML.
    #[error("{0}")]
    File(String),
    /// No such device or template in the file.
    #[error("{0}")]
    NotFound(String),
    /// The CSV or the configuration it makes has problems: one line each, nothing written.
    #[error("{}", .0.join("\n"))]
    Problems(Vec<String>),
    /// The new file could not be written.
    #[error("cannot write {}: {why}", file.display())]
    Write { file: PathBuf, why: String },
}

/// The tag list of `owner` in the configuration file `config` as CSV.
pub fn export(config: &Path, owner: &TagOwner) -> Result<String, TagCsvError> {
    let doc = read_document(config)?;
    let owner_item = find(&doc, owner)?;
    let mut out = String::new();
    write_row(&mut out, HEADER.iter().map(|h| (*h).to_owned()));
    for tag in tag_tables(owner_item.get("tags")) {
        write_row(
            &mut out,
            HEADER.iter().map(|column| {
                let key = match (*column, tag.get("byte_order"), tag.get("word_order")) {
                    ("byte_order", None, Some(_)) => "word_order",
                    _ => column,
                };
                tag.get(key).map(cell_of).unwrap_or_default()
            }),
        );
    }
    Ok(out)
}

/// Replaces the tag list of `owner` in the configuration file `config` with the tags of `csv`,
/// after checking the result; returns the number of tags written.
pub fn import(config: &Path, owner: &TagOwner, csv: &str) -> Result<usize, TagCsvError> {
    let text = std::fs::read_to_string(config)
        .map_err(|e| TagCsvError::File(format!("cannot read {}: {e}", config.display())))?;
    let mut doc: DocumentMut = text
        .parse()
        .map_err(|e| TagCsvError::File(format!("{} is not TOML: {e}", config.display())))?;
    find(&doc, owner)?;
    let (tags, mut problems) = tags_of_csv(csv);
    if !problems.is_empty() {
        return Err(TagCsvError::Problems(problems));
    }
    let count = tags.len();
    let rows: Vec<usize> = tags.iter().map(|(row, _)| *row).collect();
    let tags = tags.into_iter().map(|(_, tag)| tag).collect();
    set_tags(&mut doc, owner, tags);
    let new_text = doc.to_string();
    let dir = match config.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let issues = match config::parse_in(&new_text, &super::check::config_issues, &dir) {
        Ok(c) => {
            let mut issues = super::check::run_issues(&c);
            issues.extend(super::check::port_issues(&c).0);
            issues
        }
        Err(e) => e.issues,
    };
    if !issues.is_empty() {
        let at = owner.path();
        problems = issues.iter().map(|i| located(i, &at, &rows)).collect();
        return Err(TagCsvError::Problems(problems));
    }
    ConfigStore::new(config)
        .save_atomic(&new_text)
        .map_err(|e| TagCsvError::Write {
            file: config.to_path_buf(),
            why: e.to_string(),
        })?;
    Ok(count)
}

/// An issue of the new configuration: at a tag of the list, its CSV row and column.
fn located(issue: &ConfigIssue, owner: &str, rows: &[usize]) -> String {
    let prefix = format!("{owner}.tags[");
    let Some(rest) = issue.path.strip_prefix(&prefix) else {
        return issue.to_string();
    };
    let Some((index, key)) = rest.split_once(']') else {
        return issue.to_string();
    };
    let Ok(index) = index.parse::<usize>() else {
        return issue.to_string();
    };
    // Row 1 is the header.
    let row = rows.get(index).copied().unwrap_or(index + 2);
    let key = key.trim_start_matches('.');
    let key = if key == "word_order" {
        "byte_order"
    } else {
        key
    };
    match HEADER.iter().position(|h| *h == key) {
        Some(c) => format!("row {row}, column {} ({key}): {}", c + 1, issue.message),
        None => format!("row {row}: {}", issue.message),
    }
}

fn read_document(config: &Path) -> Result<DocumentMut, TagCsvError> {
    let text = std::fs::read_to_string(config)
        .map_err(|e| TagCsvError::File(format!("cannot read {}: {e}", config.display())))?;
    text.parse()
        .map_err(|e| TagCsvError::File(format!("{} is not TOML: {e}", config.display())))
}

/// The owner's table (a `[table]` or an inline table).
fn find<'d>(doc: &'d DocumentMut, owner: &TagOwner) -> Result<&'d Item, TagCsvError> {
    let mut item = doc.as_item();
    for key in owner.keys() {
        item = item.get(key).ok_or_else(|| {
            TagCsvError::NotFound(format!("{} is not in the configuration file", owner.path()))
        })?;
    }
    if item.is_table_like() {
        Ok(item)
    } else {
        Err(TagCsvError::NotFound(format!(
            "{} is not a table",
            owner.path()
        )))
    }
}

/// The tags of a `tags` item, as key-value views (array of tables or inline array).
fn tag_tables(item: Option<&Item>) -> Vec<Vec<(String, Value)>> {
    let to_pairs = |t: &dyn toml_edit::TableLike| {
        t.iter()
            .filter_map(|(k, v)| v.as_value().map(|v| (k.to_owned(), v.clone())))
            .collect::<Vec<_>>()
    };
    match item {
        Some(Item::ArrayOfTables(a)) => a.iter().map(|t| to_pairs(t)).collect(),
        Some(Item::Value(Value::Array(a))) => a
            .iter()
            .filter_map(Value::as_inline_table)
            .map(|t| to_pairs(t))
            .collect(),
        _ => Vec::new(),
    }
}

/// Lookup in a tag's pairs.
trait Pairs {
    fn get(&self, key: &str) -> Option<&Value>;
}

impl Pairs for Vec<(String, Value)> {
    fn get(&self, key: &str) -> Option<&Value> {
        self.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }
}

/// A TOML value as a CSV cell: a string's text, any other value as TOML writes it.
fn cell_of(value: &Value) -> String {
    match value {
        Value::String(s) => s.value().clone(),
        other => other.clone().decorated("", "").to_string(),
    }
}

/// The kind of a column's values.
#[derive(Clone, Copy)]
enum Kind {
    Text,
    Int,
    Float,
    Bool,
}

fn kind_of(column: &str) -> Kind {
    match column {
        "address" | "bit" | "registers" | "decimals" => Kind::Int,
        "scale" | "offset" => Kind::Float,
        "writable" => Kind::Bool,
        _ => Kind::Text,
    }
}

/// The tags of a CSV document, each as its keys in [`HEADER`]'s order; every problem with its
/// row and column.
/// A tag read from CSV: its row, and its keys.
type CsvTag = (usize, Vec<(&'static str, Value)>);

fn tags_of_csv(csv: &str) -> (Vec<CsvTag>, Vec<String>) {
    let mut problems = Vec::new();
    let rows = match parse_csv(csv) {
        Ok(rows) => rows,
        Err(e) => return (Vec::new(), vec![e]),
    };
    let mut rows = rows.into_iter();
    match rows.next() {
        Some((_, header)) if header.iter().map(String::as_str).eq(HEADER) => {}
        Some((_, header)) => {
            problems.push(format!(
                "row 1: the header must be exactly {}, not {}",
                HEADER.join(","),
                header.join(",")
            ));
            return (Vec::new(), problems);
        }
        None => {
            problems.push(format!("row 1: empty; the header is {}", HEADER.join(",")));
            return (Vec::new(), problems);
        }
    }
    let mut tags = Vec::new();
    for (row, cells) in rows {
        if cells.len() == 1 && cells[0].trim().is_empty() {
            continue;
        }
        if cells.len() != HEADER.len() {
            problems.push(format!(
                "row {row}: {} fields, the header has {}",
                cells.len(),
                HEADER.len()
            ));
            continue;
        }
        let mut tag = Vec::new();
        for (c, (column, cell)) in HEADER.iter().zip(&cells).enumerate() {
            let text = cell.trim();
            if text.is_empty() {
                continue;
            }
            let at = || format!("row {row}, column {} ({column})", c + 1);
            let value = match kind_of(column) {
                Kind::Text => Some(Value::from(cell.as_str())),
                Kind::Int => text.parse::<i64>().ok().map(Value::from),
                Kind::Float => text
                    .parse::<f64>()
                    .ok()
                    .filter(|f| f.is_finite())
                    .map(Value::from),
                Kind::Bool => match text {
                    "true" => Some(Value::from(true)),
                    "false" => Some(Value::from(false)),
                    _ => None,
                },
            };
            match value {
                Some(v) => tag.push((*column, v)),
                None => problems.push(format!(
                    "{}: {text:?} is not {}",
                    at(),
                    match kind_of(column) {
                        Kind::Int => "a whole number",
                        Kind::Float => "a finite number",
                        Kind::Bool => "true or false",
                        Kind::Text => "text",
                    }
                )),
            }
        }
        tags.push((row, tag));
    }
    (tags, problems)
}

/// Puts `tags` in place of the owner's tag list, in the form the file had (`[[...tags]]` tables
/// or an inline array), `[[...tags]]` tables when it had none.
fn set_tags(doc: &mut DocumentMut, owner: &TagOwner, tags: Vec<Vec<(&'static str, Value)>>) {
    let mut item = doc.as_item_mut();
    for key in owner.keys() {
        item = &mut item[key];
    }
    let inline = matches!(item.get("tags"), Some(Item::Value(Value::Array(_))))
        || item.as_inline_table().is_some();
    let new = if inline {
        let mut array = Array::new();
        for tag in tags {
            let mut t = InlineTable::new();
            for (k, v) in tag {
                t.insert(k, v);
            }
            array.push(t);
        }
        for v in array.iter_mut() {
            v.decor_mut().set_prefix("\n  ");
        }
        array.set_trailing("\n");
        array.set_trailing_comma(true);
        Item::Value(Value::Array(array))
    } else {
        let mut list = ArrayOfTables::new();
        for tag in tags {
            let mut t = Table::new();
            for (k, v) in tag {
                t.insert(k, Item::Value(v));
            }
            list.push(t);
        }
        Item::ArrayOfTables(list)
    };
    if let Some(table) = item.as_table_like_mut() {
        table.insert("tags", new);
    }
}

/// Appends one CSV row.
fn write_row(out: &mut String, cells: impl Iterator<Item = String>) {
    let mut first = true;
    for cell in cells {
        if !first {
            out.push(',');
        }
        first = false;
        if cell.contains([',', '"', '\n', '\r']) || cell != cell.trim() {
            out.push('"');
            out.push_str(&cell.replace('"', "\"\""));
            out.push('"');
        } else {
            out.push_str(&cell);
        }
    }
    out.push('\n');
}

/// The rows of a CSV document with their 1-based line numbers (of the row's first line).
fn parse_csv(text: &str) -> Result<Vec<(usize, Vec<String>)>, String> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut rows = Vec::new();
    let mut row = Vec::new();
    let mut cell = String::new();
    let mut quoted = false;
    let mut line = 1;
    let mut row_line = 1;
    let mut chars = text.chars().peekable();
    let mut at_start = true;
    while let Some(c) = chars.next() {
        if quoted {
            match c {
                '"' if chars.peek() == Some(&'"') => {
                    chars.next();
                    cell.push('"');
                }
                '"' => quoted = false,
                '\n' => {
                    line += 1;
                    cell.push(c);
                }
                _ => cell.push(c),
            }
            continue;
        }
        match c {
            '"' if at_start => quoted = true,
            ',' => {
                row.push(std::mem::take(&mut cell));
                at_start = true;
                continue;
            }
            '\r' if chars.peek() == Some(&'\n') => {}
            '\n' => {
                row.push(std::mem::take(&mut cell));
                rows.push((row_line, std::mem::take(&mut row)));
                line += 1;
                row_line = line;
                at_start = true;
                continue;
            }
            _ => cell.push(c),
        }
        at_start = false;
    }
    if quoted {
        return Err(format!("row {row_line}: a quoted field is not closed"));
    }
    if !cell.is_empty() || !row.is_empty() {
        row.push(cell);
        rows.push((row_line, row));
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_fields_quote_and_unquote() {
        let mut out = String::new();
        write_row(
            &mut out,
            ["a", "b,c", "say \"hi\"", "two\nlines", ""]
                .iter()
                .map(|s| (*s).to_owned()),
        );
        let rows = parse_csv(&out).expect("CSV");
        assert_eq!(
            rows,
            [(
                1,
                vec![
                    "a".to_owned(),
                    "b,c".to_owned(),
                    "say \"hi\"".to_owned(),
                    "two\nlines".to_owned(),
                    String::new()
                ]
            )]
        );
        assert!(parse_csv("\"open").is_err());
        assert_eq!(parse_csv("x,y\r\n1,2\r\n").expect("CRLF").len(), 2);
    }

    #[test]
    fn an_issue_at_a_tag_names_its_row_and_column() {
        let issue = ConfigIssue {
            path: "lines.a.devices.m.tags[1].scale".to_owned(),
            message: "scale 0 makes every raw value 0".to_owned(),
        };
        assert_eq!(
            located(&issue, "lines.a.devices.m", &[2, 3]),
            "row 3, column 8 (scale): scale 0 makes every raw value 0"
        );
    }
}
