//! A configuration change applied to the operator's file in place.
//!
//! The file is the operator's: its comments, the order of its tables and keys, the way values are
//! written (`0x03`, `"0.5s"`, inline tables) and the keys left out (they take their defaults)
//! stay as they are. Only what differs between the configuration in force and the new one is
//! written: a changed value replaces the old one (keeping the comment after it), a key the new
//! configuration has and the old one had not is added, a key it no longer has is removed.
//!
//! The two configurations are compared in their serialized form (every key, defaults included),
//! so a key that keeps its value is never touched, whether the file writes it out or not.

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

    #[test]
    fn text_that_is_not_toml_is_left_to_the_caller() {
        assert!(edit_in_place("[unclosed", &Table::new(), &Table::new()).is_none());
    }
}
