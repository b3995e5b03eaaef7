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
//!
//! Formula injection (OWASP, "CSV Injection"): a spreadsheet runs a cell that starts with `=`,
//! `+`, `-`, `@`, a tab or a carriage return as a formula. Export writes such a cell of a text
//! column (every column but the numbers `address`, `bit`, `registers`, `scale`, `offset`,
//! `decimals` and the bool `writable`) with a single quote `'` before it, in double quotes
//! (`"'=HYPERLINK(...)"`); a text cell that already starts with quotes before one of those
//! characters gets one quote more, so that import, which takes one leading quote off such a cell,
//! gives back the text as it was. A number (`-273.15` in `offset`) stays a number.
//!
//! Import is bounded: a CSV over [`MAX_CSV_BYTES`] is refused before it is read, and rows are
//! read one at a time from the file (never the whole file in one string), each turned into its
//! tag at once, so that memory follows the tags kept.

use std::io::BufRead;
use std::path::{Path, PathBuf};

use toml_edit::{Array, ArrayOfTables, DocumentMut, InlineTable, Item, Table, Value};

use crate::config::ConfigIssue;
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

/// The largest CSV import takes: 16 MiB. The largest sane tag list, 100 000 tags (a gateway's
/// stated ceiling) at about 100 bytes a row, is 10 MB; a larger file is refused with a clear
/// error before it is read.
pub const MAX_CSV_BYTES: u64 = 16 * 1024 * 1024;

/// The characters that make a spreadsheet read a cell as a formula (OWASP, "CSV Injection").
const FORMULA_START: [char; 6] = ['=', '+', '-', '@', '\t', '\r'];

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

/// `gateway tags export | import`.
#[derive(Debug, clap::Subcommand)]
pub enum TagsCommand {
    /// Print the tag list as CSV (header name,table,address,type,byte_order,bit,registers,scale,
    /// offset,decimals,unit,writable,description).
    Export {
        #[command(flatten)]
        owner: TagsOwnerArgs,
    },
    /// Replace the tag list in the config file with the tags of a CSV file (checked first as
    /// `gateway check` does; nothing is written on any problem; the file is replaced atomically,
    /// its comments kept, the previous version as FILE.prev).
    Import {
        #[command(flatten)]
        owner: TagsOwnerArgs,
        /// The CSV file (`-` for standard input).
        csv: PathBuf,
    },
}

/// Whose tag list: `--line L --device D`, or `--template NAME` (a `[templates.NAME]`).
#[derive(Debug, clap::Args)]
pub struct TagsOwnerArgs {
    /// The config file.
    #[arg(long, short)]
    config: PathBuf,
    /// The line of the device.
    #[arg(long, requires = "device", conflicts_with = "template")]
    line: Option<String>,
    /// The device.
    #[arg(long, requires = "line", conflicts_with = "template")]
    device: Option<String>,
    /// A template of the config's [templates] instead of a device.
    #[arg(long, required_unless_present = "line")]
    template: Option<String>,
}

// === impl TagsOwnerArgs ===

impl TagsOwnerArgs {
    fn owner(&self) -> TagOwner {
        match (&self.line, &self.device, &self.template) {
            (Some(line), Some(device), _) => TagOwner::Device {
                line: line.clone(),
                device: device.clone(),
            },
            (_, _, template) => TagOwner::Template(template.clone().unwrap_or_default()),
        }
    }
}

/// Runs `gateway tags`; the exit code: 0 done, 1 problems (printed on stderr), 2 no such file or
/// owner.
pub fn command(command: &TagsCommand) -> u8 {
    let result = match command {
        TagsCommand::Export { owner } => {
            export(&owner.config, &owner.owner()).map(|csv| print!("{csv}"))
        }
        TagsCommand::Import { owner, csv } => open_csv(csv).and_then(|reader| {
            import_from(&owner.config, &owner.owner(), reader).map(|n| {
                println!(
                    "ok: {n} tags written to {} ({})",
                    owner.config.display(),
                    owner.owner().path()
                );
            })
        }),
    };
    match result {
        Ok(()) => 0,
        Err(e @ TagCsvError::Problems(_)) => {
            eprintln!("{e}\nnothing written");
            1
        }
        Err(e) => {
            eprintln!("gateway tags: {e}");
            2
        }
    }
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
    import_from(config, owner, csv.as_bytes())
}

/// Opens the CSV file `path` (`-`: standard input) for [`import_from`]: a file over
/// [`MAX_CSV_BYTES`] is refused before a byte of it is read; standard input is read up to the
/// bound (one byte more is refused as too large).
pub fn open_csv(path: &Path) -> Result<Box<dyn BufRead>, TagCsvError> {
    use std::io::Read;
    let too_large = |size: Option<u64>| {
        let size = size.map_or_else(|| "more than that".to_owned(), |n| format!("{n} bytes"));
        TagCsvError::File(format!(
            "{} is too large: a tag list may have at most {} MiB (100 000 tags at about 100 \
             bytes a row are 10 MB), this one has {size}; split the list",
            path.display(),
            MAX_CSV_BYTES / (1024 * 1024)
        ))
    };
    let bounded = |inner: Box<dyn Read>| -> Box<dyn BufRead> {
        Box::new(Bounded {
            inner: std::io::BufReader::new(inner.take(MAX_CSV_BYTES + 1)),
            read: 0,
            error: Some(too_large(None).to_string()),
        })
    };
    if path.as_os_str() == "-" {
        return Ok(bounded(Box::new(std::io::stdin().lock())));
    }
    let file = std::fs::File::open(path)
        .map_err(|e| TagCsvError::File(format!("cannot read {}: {e}", path.display())))?;
    let size = file
        .metadata()
        .map_err(|e| TagCsvError::File(format!("cannot read {}: {e}", path.display())))?
        .len();
    if size > MAX_CSV_BYTES {
        return Err(too_large(Some(size)));
    }
    // The file may still grow while it is read: the same bound applies to what is read.
    Ok(bounded(Box::new(file)))
}

/// A reader that fails once more than [`MAX_CSV_BYTES`] came through it.
struct Bounded<R> {
    inner: R,
    read: u64,
    error: Option<String>,
}

impl<R: BufRead> std::io::Read for Bounded<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.consume_counted(n)?;
        Ok(n)
    }
}

impl<R: BufRead> BufRead for Bounded<R> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        if self.read > MAX_CSV_BYTES {
            return Err(self.too_large());
        }
        self.inner.fill_buf()
    }
    fn consume(&mut self, amount: usize) {
        self.read = self.read.saturating_add(amount as u64);
        self.inner.consume(amount);
    }
}

impl<R> Bounded<R> {
    fn too_large(&self) -> std::io::Error {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            self.error.clone().unwrap_or_default(),
        )
    }
    fn consume_counted(&mut self, n: usize) -> std::io::Result<()> {
        self.read = self.read.saturating_add(n as u64);
        if self.read > MAX_CSV_BYTES {
            return Err(self.too_large());
        }
        Ok(())
    }
}

/// [`import`] from a reader: rows are read and turned into tags one at a time.
pub fn import_from(
    config: &Path,
    owner: &TagOwner,
    csv: impl BufRead,
) -> Result<usize, TagCsvError> {
    let mut doc = read_document(config)?;
    find(&doc, owner)?;
    let (tags, mut problems) = tags_of_csv(csv);
    if !problems.is_empty() {
        return Err(TagCsvError::Problems(problems));
    }
    let count = tags.len();
    let rows: Vec<usize> = tags.iter().map(|(row, _)| *row).collect();
    set_tags(&mut doc, owner, tags.into_iter().map(|(_, tag)| tag));
    let new_text = doc.to_string();
    drop(doc);
    let dir = crate::config::check::parent_dir(config);
    let issues = match crate::plant::parse_in(&new_text, &crate::plant::check::config_issues, dir) {
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

/// A TOML value as a CSV cell: a string's text (escaped against formula injection), any other
/// value as TOML writes it.
fn cell_of(value: &Value) -> String {
    match value {
        Value::String(s) => escape_formula(s.value()),
        other => other.clone().decorated("", "").to_string(),
    }
}

/// Whether a text cell would be read as a formula, or is such a cell already escaped (one or
/// more `'` before a formula character).
fn looks_like_formula(text: &str) -> bool {
    text.trim_start_matches('\'').starts_with(FORMULA_START)
}

/// A text cell as export writes it: `'` before a cell a spreadsheet would run as a formula
/// (OWASP); [`write_row`] quotes it.
fn escape_formula(text: &str) -> String {
    if looks_like_formula(text) {
        format!("'{text}")
    } else {
        text.to_owned()
    }
}

/// A text cell as import reads it: the `'` export put before a formula character taken off.
fn unescape_formula(text: &str) -> &str {
    match text.strip_prefix('\'') {
        Some(rest) if looks_like_formula(rest) => rest,
        _ => text,
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

fn tags_of_csv(csv: impl BufRead) -> (Vec<CsvTag>, Vec<String>) {
    let mut problems = Vec::new();
    let mut rows = CsvRows::new(csv);
    match rows.next_row() {
        Err(e) => return (Vec::new(), vec![e]),
        Ok(Some((_, header))) if header.iter().map(String::as_str).eq(HEADER) => {}
        Ok(Some((_, header))) => {
            problems.push(format!(
                "row 1: the header must be exactly {}, not {}",
                HEADER.join(","),
                header.join(",")
            ));
            return (Vec::new(), problems);
        }
        Ok(None) => {
            problems.push(format!("row 1: empty; the header is {}", HEADER.join(",")));
            return (Vec::new(), problems);
        }
    }
    let mut tags = Vec::new();
    let mut more = 0usize;
    loop {
        let (row, cells) = match rows.next_row() {
            Ok(Some(row)) => row,
            Ok(None) => break,
            // The file cannot be read on (too large, not UTF-8, an unclosed quote): that is
            // the answer, before any problem of the rows.
            Err(e) => return (Vec::new(), vec![e]),
        };
        if cells.len() == 1 && cells[0].trim().is_empty() {
            continue;
        }
        if cells.len() != HEADER.len() {
            note(
                &mut problems,
                &mut more,
                format!(
                    "row {row}: {} fields, the header has {}",
                    cells.len(),
                    HEADER.len()
                ),
            );
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
                Kind::Text => Some(Value::from(unescape_formula(cell))),
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
                None => note(
                    &mut problems,
                    &mut more,
                    format!(
                        "{}: {text:?} is not {}",
                        at(),
                        match kind_of(column) {
                            Kind::Int => "a whole number",
                            Kind::Float => "a finite number",
                            Kind::Bool => "true or false",
                            Kind::Text => "text",
                        }
                    ),
                ),
            }
        }
        // Once a problem is found nothing is written: the tags are not kept.
        if problems.is_empty() {
            tags.push((row, tag));
        } else {
            tags = Vec::new();
        }
    }
    if more > 0 {
        problems.push(format!("... and {more} more problems"));
    }
    (tags, problems)
}

/// Adds a problem to the list, or counts it once the list has [`MAX_PROBLEMS`].
fn note(problems: &mut Vec<String>, more: &mut usize, problem: String) {
    if problems.len() < MAX_PROBLEMS {
        problems.push(problem);
    } else {
        *more += 1;
    }
}

/// Puts `tags` in place of the owner's tag list, in the form the file had (`[[...tags]]` tables
/// or an inline array), `[[...tags]]` tables when it had none.
fn set_tags(
    doc: &mut DocumentMut,
    owner: &TagOwner,
    tags: impl Iterator<Item = Vec<(&'static str, Value)>>,
) {
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
        // A cell escaped against formula injection (it starts with `'`) is quoted as well, as
        // OWASP's guidance asks.
        if cell.contains([',', '"', '\n', '\r']) || cell != cell.trim() || cell.starts_with('\'') {
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
#[cfg(test)]
fn parse_csv(text: &str) -> Result<Vec<(usize, Vec<String>)>, String> {
    let mut rows = CsvRows::new(text.as_bytes());
    let mut all = Vec::new();
    while let Some(row) = rows.next_row()? {
        all.push(row);
    }
    Ok(all)
}

/// The most characters one CSV row may have (a row of 13 cells; a description is free text but
/// a row of 64 KiB is no tag): a longer one is refused, so one unclosed quote cannot make one
/// row of the whole file.
const MAX_ROW_CHARS: usize = 64 * 1024;

/// The most problems an import lists; the rest are counted in one line.
const MAX_PROBLEMS: usize = 100;

/// Reads CSV rows one at a time from a reader: the memory of a row, never of the file.
struct CsvRows<R> {
    reader: R,
    /// One physical line of the file (reused).
    line_buf: String,
    /// The number of the next physical line.
    line: usize,
}

// === impl CsvRows ===

impl<R: BufRead> CsvRows<R> {
    fn new(reader: R) -> Self {
        Self {
            reader,
            line_buf: String::new(),
            line: 1,
        }
    }

    /// The next row with the number of its first line; `None` at the end.
    fn next_row(&mut self) -> Result<Option<(usize, Vec<String>)>, String> {
        let row_line = self.line;
        let mut row = Vec::new();
        let mut cell = String::new();
        let mut quoted = false;
        let mut at_start = true;
        let mut chars_in_row = 0usize;
        loop {
            self.line_buf.clear();
            let read = self
                .reader
                .read_line(&mut self.line_buf)
                .map_err(|e| match e.kind() {
                    std::io::ErrorKind::InvalidData if e.get_ref().is_some() => {
                        format!("row {}: {e}", self.line)
                    }
                    _ => format!("row {}: {e}", self.line),
                })?;
            if read == 0 {
                if quoted {
                    return Err(format!("row {row_line}: a quoted field is not closed"));
                }
                if !cell.is_empty() || !row.is_empty() {
                    row.push(cell);
                    return Ok(Some((row_line, row)));
                }
                return Ok(None);
            }
            let mut text = self.line_buf.as_str();
            if self.line == 1 {
                text = text.strip_prefix('\u{feff}').unwrap_or(text);
            }
            self.line += 1;
            chars_in_row = chars_in_row.saturating_add(text.len());
            if chars_in_row > MAX_ROW_CHARS {
                return Err(format!(
                    "row {row_line}: longer than {MAX_ROW_CHARS} bytes (an unclosed quote?)"
                ));
            }
            let mut chars = text.chars().peekable();
            while let Some(c) = chars.next() {
                if quoted {
                    match c {
                        '"' if chars.peek() == Some(&'"') => {
                            chars.next();
                            cell.push('"');
                        }
                        '"' => quoted = false,
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
                        return Ok(Some((row_line, row)));
                    }
                    _ => cell.push(c),
                }
                at_start = false;
            }
        }
    }
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

    #[test]
    fn formula_cells_are_escaped_and_read_back() {
        for text in [
            "=HYPERLINK(\"http://evil.example\",\"x\")",
            "+cmd|' /C calc'!A0",
            "@SUM(A1:A2)",
            "-x",
            "\tindent",
            "\rreturn",
            "'=already quoted once",
            "''+twice",
        ] {
            let cell = escape_formula(text);
            assert!(cell.starts_with('\''), "{text:?} -> {cell:?}");
            let mut out = String::new();
            write_row(&mut out, [cell.clone()].into_iter());
            assert!(out.starts_with("\"'"), "quoted: {out:?}");
            let rows = parse_csv(&out).expect("CSV");
            assert_eq!(unescape_formula(&rows[0].1[0]), text);
        }
        // Plain text, and a quote before anything else, pass unchanged both ways.
        for text in ["degC", "it's", "'quoted'", "a=b", ""] {
            assert_eq!(escape_formula(text), text);
            assert_eq!(unescape_formula(text), text);
        }
        // A number stays a number: only text columns are escaped.
        assert_eq!(cell_of(&Value::from(-1.5)), "-1.5");
        assert_eq!(cell_of(&Value::from("-1.5")), "'-1.5");
    }

    #[test]
    fn an_unclosed_quote_stops_at_the_row_bound() {
        let mut text = String::from("a,\"b\n");
        for _ in 0..2000 {
            text.push_str(&"x".repeat(63));
            text.push('\n');
        }
        let error = parse_csv(&text).expect_err("too long");
        assert!(error.contains("row 1: longer than 65536 bytes"), "{error}");
    }

    #[test]
    fn problems_are_listed_up_to_the_bound_then_counted() {
        let mut csv = HEADER.join(",");
        csv.push('\n');
        for _ in 0..(MAX_PROBLEMS + 5) {
            csv.push_str("t,input,eight,,,,,,,,,,\n");
        }
        let (tags, problems) = tags_of_csv(csv.as_bytes());
        assert!(tags.is_empty());
        assert_eq!(problems.len(), MAX_PROBLEMS + 1);
        assert_eq!(
            problems.last().map(String::as_str),
            Some("... and 5 more problems")
        );
    }
}
