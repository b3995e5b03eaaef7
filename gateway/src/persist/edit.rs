//! A configuration change applied to the operator's file in place.
//!
//! The file is the operator's: its comments, the order of its tables and keys, the way values are
//! written (`0x03`, `"0.5s"`, inline tables) and the keys left out (they take their defaults)
//! stay as they are. Only what differs between the configuration in force and the new one is
//! written: a changed value replaces the old one (keeping the comment after it), a key the new
//! configuration has and the old one had not is added, a key it no longer has is removed.
//!
//! Two ways in:
//!
//! - [`edit_in_place`]: a change made in code (two configurations). They are compared in their
//!   serialized form (every key, defaults included), so a key that keeps its value is never
//!   touched, whether the file writes it out or not.
//! - [`merge_table`] / [`merge_item`]: a document a client sent (a REST body, JSON or TOML). The
//!   file is made to say what the body says, key by key: the client's keys in the client's order
//!   and spelling where the file had nothing, the file's spelling (`0x0D`, not `13`) and comment
//!   where the value means the same. No default is written that neither side wrote.

use toml::{Table, Value};
use toml_edit::{DocumentMut, Item, TableLike};

/// `text` (the file in force) with the change from `old` to `new` applied, or `None` when the
/// text is not TOML (the caller then writes the whole configuration).
pub(super) fn edit_in_place(text: &str, old: &Table, new: &Table) -> Option<String> {
    let mut doc: DocumentMut = text.parse().ok()?;
    edit_table(doc.as_table_mut(), false, old, new);
    Some(doc.to_string())
}

/// Applies the difference `old` -> `new` to `table` (an inline table when `inline`).
fn edit_table(table: &mut dyn TableLike, inline: bool, old: &Table, new: &Table) {
    let gone: Vec<String> = old
        .keys()
        .filter(|k| !new.contains_key(*k))
        .cloned()
        .collect();
    for key in gone {
        table.remove(&key);
    }
    for (key, new_value) in new {
        let old_value = old.get(key);
        if old_value == Some(new_value) {
            continue;
        }
        match (old_value, table.get_mut(key)) {
            (Some(old_value), Some(item)) => edit_item(item, old_value, new_value),
            (Some(Value::Table(old_table)), None) => {
                // A table the file leaves out (all defaults): only the changed keys go in.
                if let Value::Table(new_table) = new_value {
                    let added = if inline {
                        Item::Value(toml_edit::Value::InlineTable(toml_edit::InlineTable::new()))
                    } else {
                        let mut t = toml_edit::Table::new();
                        t.set_implicit(new_table.values().all(Value::is_table));
                        Item::Table(t)
                    };
                    table.insert(key, added);
                    if let Some(item) = table.get_mut(key) {
                        edit_item(item, &Value::Table(old_table.clone()), new_value);
                    }
                } else {
                    insert_new(table, inline, key, new_value);
                }
            }
            _ => insert_new(table, inline, key, new_value),
        }
    }
}

/// Applies the difference `old` -> `new` to the file's `item`.
fn edit_item(item: &mut Item, old: &Value, new: &Value) {
    match (old, new) {
        (Value::Table(old_table), Value::Table(new_table)) => {
            let inline = item.is_value();
            if let Some(table) = item.as_table_like_mut() {
                edit_table(table, inline, old_table, new_table);
                return;
            }
        }
        (Value::Array(old_array), Value::Array(new_array))
            if old_array.len() == new_array.len() =>
        {
            if let Item::ArrayOfTables(tables) = item {
                if tables.len() == new_array.len() {
                    for (i, (o, n)) in old_array.iter().zip(new_array).enumerate() {
                        if let (Value::Table(o), Value::Table(n), Some(t)) =
                            (o, n, tables.get_mut(i))
                        {
                            edit_table(t, false, o, n);
                        }
                    }
                    return;
                }
            }
            if let Some(array) = item.as_array_mut() {
                if array.len() == new_array.len() {
                    for (i, (o, n)) in old_array.iter().zip(new_array).enumerate() {
                        if o == n {
                            continue;
                        }
                        let Some(element) = array.get_mut(i) else {
                            continue;
                        };
                        match (o, n, element.as_inline_table_mut()) {
                            (Value::Table(o), Value::Table(n), Some(t)) => {
                                edit_table(t, true, o, n);
                            }
                            _ => {
                                if let Some(v) = to_value(n) {
                                    replace_value(element, v);
                                }
                            }
                        }
                    }
                    return;
                }
            }
        }
        _ => {}
    }
    // A value of another shape: the whole item is replaced, in the form it had (a table stays a
    // table, a value stays a value with its comment).
    let Some(replacement) = to_item(new) else {
        return;
    };
    match item {
        Item::Value(current) => match replacement.into_value() {
            Ok(v) => replace_value(current, v),
            Err(other) => *item = other,
        },
        _ => *item = replacement,
    }
}

/// Replaces `current` by `new`, keeping the spaces and the comment around it.
fn replace_value(current: &mut toml_edit::Value, mut new: toml_edit::Value) {
    *new.decor_mut() = current.decor().clone();
    *current = new;
}

/// Adds `key = value` to `table` (a standard table gets sub-tables as `[tables]`, an inline
/// table inline values).
fn insert_new(table: &mut dyn TableLike, inline: bool, key: &str, value: &Value) {
    let Some(item) = to_item(value) else {
        return;
    };
    let item = if inline {
        match item.into_value() {
            Ok(v) => Item::Value(v),
            Err(_) => return,
        }
    } else {
        item
    };
    table.insert(key, item);
}

/// `value` as an item of a TOML document, in the form `toml` writes it (tables as `[tables]`,
/// arrays of tables as `[[arrays]]`), placed after the tables before it.
fn to_item(value: &Value) -> Option<Item> {
    let mut wrapper = Table::new();
    wrapper.insert("v".to_owned(), value.clone());
    let text = toml::to_string(&wrapper).ok()?;
    let mut doc: DocumentMut = text.parse().ok()?;
    let mut item = doc.as_table_mut().remove("v")?;
    forget_positions(&mut item);
    Some(item)
}

/// Clears the document positions `item`'s tables had in the text they were parsed from, so
/// that they are written where they are inserted.
fn forget_positions(item: &mut Item) {
    match item {
        Item::Table(t) => {
            t.set_position(None);
            for (_, child) in t.iter_mut() {
                forget_positions(child);
            }
        }
        Item::ArrayOfTables(tables) => {
            for t in tables.iter_mut() {
                t.set_position(None);
                for (_, child) in t.iter_mut() {
                    forget_positions(child);
                }
            }
        }
        Item::None | Item::Value(_) => {}
    }
}

/// `value` as an inline TOML value.
fn to_value(value: &Value) -> Option<toml_edit::Value> {
    to_item(value)?.into_value().ok()
}

// === a document sent by a client ===

/// Makes the file's `table` say what the client's `body` says (a table it sends replaces the
/// file's): a key the body leaves out is removed, a key the file does not have is added as the
/// client wrote it and in its order, a value that means what the file's means (`0x0D` and `13`,
/// `"500ms"` written the same) is left as the file spells it, with its comment; a changed one
/// takes the client's spelling and keeps the file's comment. `inline` when `table` is an inline
/// table of the file.
pub(crate) fn merge_table(table: &mut dyn TableLike, inline: bool, body: &dyn TableLike) {
    let gone: Vec<String> = table
        .iter()
        .map(|(k, _)| k.to_owned())
        .filter(|k| body.get(k).is_none_or(Item::is_none))
        .collect();
    for key in gone {
        table.remove(&key);
    }
    for (key, body_item) in body.iter() {
        if body_item.is_none() {
            continue;
        }
        match table.get_mut(key) {
            Some(item) if !item.is_none() => merge_item(item, body_item),
            _ => {
                let Some(item) = placed(body_item, inline) else {
                    continue;
                };
                table.remove(key);
                match body.key(key) {
                    Some(k) => {
                        table.entry_format(k).or_insert(item);
                    }
                    None => {
                        table.insert(key, item);
                    }
                }
            }
        }
    }
}

/// Makes the file's `item` say what `body` says (see [`merge_table`]).
pub(crate) fn merge_item(item: &mut Item, body: &Item) {
    // Tables and arrays are walked down to their values (only a value is compared whole), so
    // that a large document is compared once, not once per level.
    if let Some(body_table) = body.as_table_like() {
        let inline = item.is_value();
        if let Some(table) = item.as_table_like_mut() {
            merge_table(table, inline, body_table);
            return;
        }
    }
    match item {
        Item::ArrayOfTables(tables) => {
            let body_tables = tables_of(body);
            if body_tables.len() == tables.len() && !body_tables.is_empty() {
                for (table, b) in tables.iter_mut().zip(body_tables) {
                    merge_table(table, false, b);
                }
                return;
            }
        }
        Item::Value(toml_edit::Value::Array(array)) => {
            if let Some(toml_edit::Value::Array(body_array)) = body.as_value() {
                if body_array.len() == array.len() {
                    for (element, b) in array.iter_mut().zip(body_array.iter()) {
                        merge_value(element, b);
                    }
                    return;
                }
            }
        }
        _ => {}
    }
    if plain(item) == plain(body) {
        return;
    }
    let inline = item.is_value();
    let Some(replacement) = placed(body, inline) else {
        return;
    };
    match (item, replacement) {
        (Item::Value(current), Item::Value(new)) => replace_keeping_comment(current, new),
        (item, replacement) => *item = replacement,
    }
}

/// Replaces `current` by the client's `new`: the file's spaces and comment stay, unless only the
/// client wrote a comment.
fn replace_keeping_comment(current: &mut toml_edit::Value, new: toml_edit::Value) {
    let has_comment = |v: &toml_edit::Value| {
        v.decor()
            .suffix()
            .and_then(toml_edit::RawString::as_str)
            .is_some_and(|s| s.contains('#'))
    };
    if has_comment(&new) && !has_comment(current) {
        *current = new;
    } else {
        replace_value(current, new);
    }
}

/// Makes the file's `value` (in an array or inline table) say what `body` says.
fn merge_value(value: &mut toml_edit::Value, body: &toml_edit::Value) {
    if plain_value(value) == plain_value(body) {
        return;
    }
    match (value, body) {
        (toml_edit::Value::InlineTable(table), toml_edit::Value::InlineTable(b)) => {
            merge_table(table, true, b);
        }
        (toml_edit::Value::Array(array), toml_edit::Value::Array(b)) if array.len() == b.len() => {
            for (element, b) in array.iter_mut().zip(b.iter()) {
                merge_value(element, b);
            }
        }
        (value, body) => replace_keeping_comment(value, body.clone()),
    }
}

/// The tables of an array of tables, or of an array of inline tables.
fn tables_of(item: &Item) -> Vec<&dyn TableLike> {
    match item {
        Item::ArrayOfTables(tables) => tables.iter().map(|t| t as &dyn TableLike).collect(),
        Item::Value(toml_edit::Value::Array(array)) => {
            let tables: Vec<&dyn TableLike> = array
                .iter()
                .filter_map(|v| v.as_inline_table().map(|t| t as &dyn TableLike))
                .collect();
            if tables.len() == array.len() {
                tables
            } else {
                Vec::new()
            }
        }
        _ => Vec::new(),
    }
}

/// A copy of the client's `item` to put into the file: inline (a value) in an inline table,
/// its tables written where it is inserted.
fn placed(item: &Item, inline: bool) -> Option<Item> {
    let mut item = item.clone();
    forget_positions(&mut item);
    if inline {
        return item.into_value().ok().map(Item::Value);
    }
    (!item.is_none()).then_some(item)
}

/// What an item means, as a plain TOML value (its spelling, comments and layout left aside).
pub(crate) fn plain(item: &Item) -> Option<Value> {
    match item {
        Item::None => None,
        Item::Value(v) => Some(plain_value(v)),
        Item::Table(t) => Some(Value::Table(plain_table(t))),
        Item::ArrayOfTables(tables) => Some(Value::Array(
            tables
                .iter()
                .map(|t| Value::Table(plain_table(t)))
                .collect(),
        )),
    }
}

/// What a table means (see [`plain`]).
pub(crate) fn plain_table(table: &dyn TableLike) -> Table {
    table
        .iter()
        .filter_map(|(k, item)| Some((k.to_owned(), plain(item)?)))
        .collect()
}

/// What a value means (see [`plain`]).
fn plain_value(value: &toml_edit::Value) -> Value {
    use toml_edit::Value as V;
    match value {
        V::String(s) => Value::String(s.value().clone()),
        V::Integer(i) => Value::Integer(*i.value()),
        V::Float(f) => Value::Float(*f.value()),
        V::Boolean(b) => Value::Boolean(*b.value()),
        V::Datetime(d) => {
            let text = d.value().to_string();
            text.parse().map_or(Value::String(text), Value::Datetime)
        }
        V::Array(a) => Value::Array(a.iter().map(plain_value).collect()),
        V::InlineTable(t) => Value::Table(
            t.iter()
                .map(|(k, v)| (k.to_owned(), plain_value(v)))
                .collect(),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(text: &str) -> Table {
        text.parse().expect("test TOML")
    }

    #[test]
    fn a_changed_key_keeps_comments_order_and_omissions() {
        let file = "# the plant's gateway\n[gateway]\nname = \"a\" # shown in metrics\n\n\
                    # the drive\n[lines.drive]\nport = \"/dev/ttyS0\"\nbaud = 19200\n";
        let old = table("[gateway]\nname = \"a\"\ndepth = 10\n[lines.drive]\nport = \"/dev/ttyS0\"\nbaud = 19200\nparity = \"even\"\n");
        let mut new = old.clone();
        new["lines"]["drive"]
            .as_table_mut()
            .unwrap()
            .insert("baud".into(), Value::Integer(9600));
        new["gateway"]
            .as_table_mut()
            .unwrap()
            .insert("name".into(), Value::String("b".into()));
        let edited = edit_in_place(file, &old, &new).unwrap();
        assert_eq!(
            edited,
            "# the plant's gateway\n[gateway]\nname = \"b\" # shown in metrics\n\n\
             # the drive\n[lines.drive]\nport = \"/dev/ttyS0\"\nbaud = 9600\n"
        );
    }

    #[test]
    fn keys_and_tables_are_added_and_removed() {
        let file = "[lines.a]\nport = \"x\" # a\n\n[lines.b]\nport = \"y\"\n";
        let old = table("[lines.a]\nport = \"x\"\nbaud = 1\n[lines.b]\nport = \"y\"\nbaud = 1\n[zenoh]\nmode = \"peer\"\n");
        let new = table("[lines.a]\nport = \"x\"\nbaud = 2\n[lines.c]\nport = \"z\"\nbaud = 1\n[zenoh]\nmode = \"client\"\n");
        let edited = edit_in_place(file, &old, &new).unwrap();
        let parsed: Table = edited.parse().unwrap();
        assert_eq!(parsed["lines"]["a"]["baud"].as_integer(), Some(2));
        assert!(parsed["lines"].get("b").is_none(), "{edited}");
        assert_eq!(parsed["lines"]["c"]["port"].as_str(), Some("z"));
        assert_eq!(parsed["zenoh"]["mode"].as_str(), Some("client"));
        assert!(
            edited.starts_with("[lines.a]\nport = \"x\" # a\n"),
            "{edited}"
        );
    }

    #[test]
    fn arrays_of_tables_and_inline_tables_are_edited_element_by_element() {
        let file = "[[poll]]\nname = \"fast\" # the status\nranges = [\n  { table = \"holding\", start = 1, count = 9 }, # ETA\n]\n";
        let old = table("[[poll]]\nname = \"fast\"\nperiod = \"1s\"\nranges = [{ table = \"holding\", start = 1, count = 9 }]\n");
        let mut new = old.clone();
        new["poll"][0]["ranges"][0]
            .as_table_mut()
            .unwrap()
            .insert("count".into(), Value::Integer(4));
        let edited = edit_in_place(file, &old, &new).unwrap();
        assert_eq!(
            edited,
            "[[poll]]\nname = \"fast\" # the status\nranges = [\n  { table = \"holding\", start = 1, count = 4 }, # ETA\n]\n"
        );
    }

    /// The file after the client's `body` (TOML) was merged into its root.
    fn merged(file: &str, body: &str) -> String {
        let mut doc: DocumentMut = file.parse().unwrap();
        let body: DocumentMut = body.parse().unwrap();
        merge_table(doc.as_table_mut(), false, body.as_table());
        doc.to_string()
    }

    #[test]
    fn a_body_that_means_what_the_file_says_changes_nothing() {
        let file = "# the plant\n[gateway]\nname = \"a\" # shown in metrics\n\n\
                    [lines.term]\nport = \"/dev/ttyS1\"\nend_chars = [0x0D, 0x0A] # CR LF\n\
                    ranges = [\n  { start = 0x10, count = 2 }, # first\n]\n";
        let body = "[lines.term]\nend_chars = [13, 10]\nport = \"/dev/ttyS1\"\n\
                    ranges = [{ count = 2, start = 16 }]\n[gateway]\nname = \"a\"\n";
        assert_eq!(merged(file, body), file);
    }

    #[test]
    fn changed_values_take_the_clients_spelling_and_keep_the_files_comment() {
        let file = "[lines.term]\nport = \"/dev/ttyS1\" # left\nbaud = 9600 # the PLC's\n\
                    end_chars = [0x0D, 0x0A]\nparity = \"even\"\n";
        // baud changed, end_chars the same in decimal, parity left out, two keys added.
        let body = "[lines.term]\nport = \"/dev/ttyS1\"\nbaud = 19200\nend_chars = [13, 10]\n\
                    stx = 0x02\nunit_id = 5\n";
        assert_eq!(
            merged(file, body),
            "[lines.term]\nport = \"/dev/ttyS1\" # left\nbaud = 19200 # the PLC's\n\
             end_chars = [0x0D, 0x0A]\nstx = 0x02\nunit_id = 5\n"
        );
        // One element of an array changes: the others keep their spelling.
        let edited = merged("end_chars = [0x0D, 0x0A]\n", "end_chars = [13, 0x03]\n");
        assert_eq!(edited, "end_chars = [0x0D, 0x03]\n");
    }

    #[test]
    fn arrays_of_tables_are_merged_table_by_table_or_replaced_when_their_count_changes() {
        let file = "[[poll]]\nname = \"fast\" # the status\nperiod = \"1s\"\n";
        assert_eq!(
            merged(file, "[[poll]]\nname = \"fast\"\nperiod = \"2s\"\n"),
            "[[poll]]\nname = \"fast\" # the status\nperiod = \"2s\"\n"
        );
        let two = merged(
            file,
            "[[poll]]\nname = \"fast\"\n[[poll]]\nname = \"slow\"\n",
        );
        let parsed: Table = two.parse().unwrap();
        assert_eq!(parsed["poll"].as_array().map(Vec::len), Some(2), "{two}");
    }

    #[test]
    fn plain_values_compare_meaning_not_spelling() {
        let a: DocumentMut = "x = 0x0D\ny = 'a'\nz = 1_000\n".parse().unwrap();
        let b: DocumentMut = "z = 1000\ny = \"a\"\nx = 13\n".parse().unwrap();
        assert_eq!(plain_table(a.as_table()), plain_table(b.as_table()));
    }

    #[test]
    fn text_that_is_not_toml_is_left_to_the_caller() {
        assert!(edit_in_place("[unclosed", &Table::new(), &Table::new()).is_none());
    }
}
