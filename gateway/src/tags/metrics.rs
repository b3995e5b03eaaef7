//! Process values on `/metrics` (`[http] tag_metrics = true`): `gateway_tag_value` and
//! `gateway_tag_quality`, rendered at scrape time from the process image.
//!
//! The tags are not kept as Prometheus series: a series per tag would cost a label lookup at
//! every image update, with the option on or off, and would outlive a tag removed by a
//! configuration change. Instead each scrape reads the tags through the tag directory (as REST
//! does) and writes the two families straight into the exposition text. Off, nothing is done at
//! all; on, a scrape costs one image read per selected tag and about 130 bytes of text per tag
//! with short names (docs/metrics.md has the figures at 10 000 tags).
//!
//! - `gateway_tag_value{line,device,tag,unit}`: the engineering value of every numeric and bool
//!   tag (bool as 0/1) whose quality is `good`. Any other quality leaves the tag out, so that a
//!   graph shows a gap instead of a held or special value.
//! - `gateway_tag_quality{line,device,tag,quality}` = 1: the quality word of each of those tags
//!   (`good`, `out_of_range`, `off`, `not_defined`, `rejected`, `stale`, `comm_failure`, as REST
//!   and zenoh show it), `unknown` while no poll has answered for its registers.
//!
//! `[http] tag_metrics_filter` narrows the tags to those a key expression over
//! `<line>/<device>/<tag>` includes, matched as `[[zenoh.publish.tags]] key` is. The selection is
//! worked out once per tag directory and filter (a configuration change makes a new directory),
//! not at every scrape.

use std::fmt::Write as _;
use std::sync::{Arc, Mutex, PoisonError, Weak};

use proto_core::profiles::{DataType, Value};
use zenoh::key_expr::{keyexpr, OwnedKeyExpr};

use super::TagDirectory;
use crate::config::HttpConfig;
use crate::image::ProcessImage;

/// The family of the good values.
const TAG_VALUE: &str = "gateway_tag_value";
/// The family of the quality words.
const TAG_QUALITY: &str = "gateway_tag_quality";
/// The `quality` of a tag whose registers no poll has answered yet.
const QUALITY_UNKNOWN: &str = "unknown";

/// Renders the tag families; keeps the selection of the last directory and filter.
#[derive(Debug, Default)]
pub struct TagValues {
    selection: Mutex<Option<Selection>>,
}

/// The tags `filter` selects from a directory, in the directory's order.
#[derive(Debug)]
struct Selection {
    /// The directory it was made for (a weak reference keeps its address from being reused).
    tags: Weak<TagDirectory>,
    filter: Vec<String>,
    selected: Arc<[bool]>,
}

// === impl TagValues ===

impl TagValues {
    /// Nothing selected yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends `gateway_tag_value` and `gateway_tag_quality` of the tags of `tags` to `out`
    /// when `http.tag_metrics` is on; nothing when it is off.
    pub fn render(
        &self,
        out: &mut String,
        http: &HttpConfig,
        tags: &Arc<TagDirectory>,
        image: &ProcessImage,
    ) {
        if !http.tag_metrics {
            return;
        }
        let selected = self.selected(tags, &http.tag_metrics_filter);
        let mut values = String::with_capacity(selected.len() * 96);
        let mut qualities = String::with_capacity(selected.len() * 96);
        for (entry, _) in tags
            .iter()
            .zip(selected.iter())
            .filter(|(entry, on)| **on && is_numeric(entry.data_type()))
        {
            let reading = tags.read(image, entry);
            let quality = reading.as_ref().map_or(QUALITY_UNKNOWN, |r| r.quality);
            let labels = Labels {
                line: entry.line(),
                device: entry.device(),
                tag: entry.name(),
            };
            if let Some(r) = reading.as_ref().filter(|r| r.quality == GOOD) {
                if let Some(v) = number(&r.value) {
                    values.push_str(TAG_VALUE);
                    labels.write(&mut values, "unit", &r.unit);
                    push_number(&mut values, v);
                }
            }
            qualities.push_str(TAG_QUALITY);
            labels.write(&mut qualities, "quality", quality);
            qualities.push_str(" 1\n");
        }
        out.reserve(values.len() + qualities.len() + 512);
        out.push_str(
            "# HELP gateway_tag_value Value of a tag in good quality, in its engineering unit \
             (bool 0/1); [http] tag_metrics.\n# TYPE gateway_tag_value gauge\n",
        );
        out.push_str(&values);
        out.push_str(
            "# HELP gateway_tag_quality The current quality word of a tag (1); [http] \
             tag_metrics.\n# TYPE gateway_tag_quality gauge\n",
        );
        out.push_str(&qualities);
    }

    /// Which tags of `tags` the filter selects, worked out again only for a new directory or
    /// filter.
    fn selected(&self, tags: &Arc<TagDirectory>, filter: &[String]) -> Arc<[bool]> {
        let mut cached = self
            .selection
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(s) = cached.as_ref() {
            if Weak::ptr_eq(&s.tags, &Arc::downgrade(tags)) && s.filter == filter {
                return Arc::clone(&s.selected);
            }
        }
        let rules: Vec<&keyexpr> = filter
            .iter()
            .filter_map(|k| keyexpr::new(k.as_str()).ok())
            .collect();
        let selected: Arc<[bool]> = tags
            .iter()
            .map(|e| filter.is_empty() || includes(&rules, e.line(), e.device(), e.name()))
            .collect();
        *cached = Some(Selection {
            tags: Arc::downgrade(tags),
            filter: filter.to_vec(),
            selected: Arc::clone(&selected),
        });
        selected
    }
}

/// The quality word of a good value (`Quality::Good.as_str()`).
const GOOD: &str = "good";

/// Whether one of `rules` includes the key `<line>/<device>/<tag>`; a name that makes no key
/// (it holds `*`, `$`, `?` or `#`) is included by none.
fn includes(rules: &[&keyexpr], line: &str, device: &str, tag: &str) -> bool {
    let Ok(key) = OwnedKeyExpr::new(format!("{line}/{device}/{tag}")) else {
        return false;
    };
    rules.iter().any(|rule| rule.includes(&key))
}

/// Numeric and bool tags have a value here; text tags do not.
fn is_numeric(data_type: DataType) -> bool {
    !matches!(data_type, DataType::String { .. })
}

/// A number, as the text format writes it.
enum Number {
    Int(i64),
    UInt(u64),
    Float(f64),
}

fn number(value: &Value) -> Option<Number> {
    match value {
        Value::Int(v) => Some(Number::Int(*v)),
        Value::UInt(v) => Some(Number::UInt(*v)),
        Value::Float(v) => Some(Number::Float(*v)),
        Value::Bool(v) => Some(Number::Int(i64::from(*v))),
        Value::Text(_) => None,
    }
}

/// ` VALUE\n` (`NaN`, `+Inf`, `-Inf` as the text format spells them).
fn push_number(out: &mut String, v: Number) {
    // Writing to a String cannot fail.
    let _ = match v {
        Number::Int(i) => writeln!(out, " {i}"),
        Number::UInt(u) => writeln!(out, " {u}"),
        Number::Float(f) if f.is_nan() => writeln!(out, " NaN"),
        Number::Float(f) if f.is_infinite() => {
            writeln!(out, " {}", if f > 0.0 { "+Inf" } else { "-Inf" })
        }
        Number::Float(f) => writeln!(out, " {f}"),
    };
}

/// The labels every sample of a tag has.
struct Labels<'a> {
    line: &'a str,
    device: &'a str,
    tag: &'a str,
}

impl Labels<'_> {
    /// `{line="..",device="..",tag="..",KEY=".."}`.
    fn write(&self, out: &mut String, key: &str, value: &str) {
        out.push_str("{line=\"");
        escape(out, self.line);
        out.push_str("\",device=\"");
        escape(out, self.device);
        out.push_str("\",tag=\"");
        escape(out, self.tag);
        out.push_str("\",");
        out.push_str(key);
        out.push_str("=\"");
        escape(out, value);
        out.push_str("\"}");
    }
}

/// A label value escaped as the text format 0.0.4 requires: backslash, double quote, line feed.
fn escape(out: &mut String, value: &str) {
    if !value.contains(['\\', '"', '\n']) {
        out.push_str(value);
        return;
    }
    for c in value.chars() {
        match c {
            '\\' => out.push_str("\\\\"),
            '"' => out.push_str("\\\""),
            '\n' => out.push_str("\\n"),
            c => out.push(c),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::image::{ImageConfig, Table};

    /// The demo's tags with ACC good (1.3 s) and ETA "not available" (0x8000) in the image.
    fn demo() -> (crate::plant::Config, Arc<TagDirectory>, ProcessImage) {
        let config = crate::plant::demo();
        let tags = Arc::new(TagDirectory::from_config(&config));
        let image = ProcessImage::new(ImageConfig::default());
        for (tag, word) in [("ACC", 13), ("ETA", 0x8000)] {
            let entry = tags.find("drive", "atv71", tag).expect("Altivar tag");
            let fresh = Some(Duration::from_secs(5));
            image.store_words(2, Table::HoldingRegisters, entry.address(), &[word], fresh);
        }
        (config, tags, image)
    }

    #[tokio::test]
    async fn good_tags_have_a_value_and_every_tag_its_quality() {
        let (config, tags, image) = demo();
        let values = TagValues::new();
        let mut http = config.http.clone();
        let mut text = String::new();
        values.render(&mut text, &http, &tags, &image);
        assert_eq!(text, "", "off by default");

        http.tag_metrics = true;
        values.render(&mut text, &http, &tags, &image);
        let acc = tags.find("drive", "atv71", "ACC").expect("ACC");
        let line = format!(
            "gateway_tag_value{{line=\"drive\",device=\"atv71\",tag=\"ACC\",unit=\"{}\"}} 1.3\n",
            acc.unit()
        );
        assert!(text.contains(&line), "{line} missing in\n{text}");
        assert!(
            !text.contains("tag=\"ETA\",unit"),
            "ETA is not good:\n{text}"
        );
        for quality in [
            r#"gateway_tag_quality{line="drive",device="atv71",tag="ACC",quality="good"} 1"#,
            r#"gateway_tag_quality{line="drive",device="atv71",tag="ETA",quality="not_defined"} 1"#,
            r#"gateway_tag_quality{line="drive",device="atv71",tag="DEC",quality="unknown"} 1"#,
        ] {
            assert!(text.contains(quality), "{quality} missing in\n{text}");
        }
        assert_eq!(text.matches("# TYPE gateway_tag_value gauge\n").count(), 1);

        // Narrowed to one tag by a key expression.
        http.tag_metrics_filter = vec!["drive/atv71/ACC".into()];
        let mut narrow = String::new();
        values.render(&mut narrow, &http, &tags, &image);
        assert_eq!(
            narrow.matches("gateway_tag_quality{").count(),
            1,
            "{narrow}"
        );
        assert!(narrow.contains(&line), "{narrow}");
    }

    #[test]
    fn label_values_are_escaped() {
        let mut out = String::new();
        escape(&mut out, "a\\b\"c\nd °C");
        assert_eq!(out, "a\\\\b\\\"c\\nd °C");
    }

    #[test]
    fn numbers_are_written_as_the_text_format_reads_them() {
        let text = |v| {
            let mut out = String::new();
            push_number(&mut out, v);
            out
        };
        assert_eq!(text(Number::Int(-3)), " -3\n");
        assert_eq!(text(Number::UInt(u64::MAX)), " 18446744073709551615\n");
        assert_eq!(text(Number::Float(19.95)), " 19.95\n");
        assert_eq!(text(Number::Float(f64::NAN)), " NaN\n");
        assert_eq!(text(Number::Float(f64::NEG_INFINITY)), " -Inf\n");
        assert_eq!(text(Number::Float(f64::INFINITY)), " +Inf\n");
    }

    #[test]
    fn filters_match_line_device_and_tag_as_zenoh_keys() {
        let rule = |k: &'static str| keyexpr::new(k).expect("key expression");
        let drive = [rule("drive/**")];
        assert!(includes(&drive, "drive", "atv71", "ETA"));
        assert!(!includes(&drive, "ksvario", "ks", "PV"));
        let one = [rule("*/ks/PV"), rule("drive/atv71/ACC")];
        assert!(includes(&one, "ksvario", "ks", "PV"));
        assert!(includes(&one, "drive", "atv71", "ACC"));
        assert!(!includes(&one, "drive", "atv71", "DEC"));
        // A name that makes no key is selected by no filter.
        assert!(!includes(&[rule("**")], "drive", "atv71", "a*b"));
    }
}
