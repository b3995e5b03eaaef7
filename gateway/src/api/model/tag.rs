//! Tags (named device values) and the RS232 signals of a line.

use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

use super::Timestamp;
use crate::image::Quality;
use crate::tags::TagReading;

/// A value: a number, a bit or a text. Whole numbers are JSON integers, exact up to 64 bits
/// (a `u64` above `i64::MAX` too).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ScalarValue {
    Bool(bool),
    Int(i64),
    UInt(u64),
    Float(f64),
    Text(String),
}

/// A boolean, a number or a string. Integers are numbers too, so the schema has no separate
/// integer branch: `oneOf` branches must not overlap (a value has to match exactly one).
impl utoipa::PartialSchema for ScalarValue {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::schema::{ObjectBuilder, OneOfBuilder, Type};
        OneOfBuilder::new()
            .item(ObjectBuilder::new().schema_type(Type::Boolean))
            .item(ObjectBuilder::new().schema_type(Type::Number))
            .item(ObjectBuilder::new().schema_type(Type::String))
            .description(Some(
                "A value: a number (whole numbers exact up to 64 bits), a bit, or the text of a string tag",
            ))
            .into()
    }
}

impl ToSchema for ScalarValue {}

// === impl ScalarValue ===

impl ScalarValue {
    /// The value as a number (a bit as 0 or 1, a text as NaN).
    pub fn as_f64(&self) -> f64 {
        proto_core::profiles::Value::from(self.clone()).as_f64()
    }
}

/// How far a value can be trusted (the image's quality of the value, and the KS vario's special values).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum TagQuality {
    Good,
    /// Not refreshed within its poll period.
    Stale,
    /// The device reports the value as not defined (KS vario 31000 / 1.5E37, Altivar 8000h).
    NotDefined,
    /// The device reports the function as off (KS vario 32000).
    Off,
    /// The device reports the value as out of range (KS vario 8000h).
    OutOfRange,
    /// The device answered the poll of the value with an exception.
    Rejected,
    /// The device does not answer.
    CommFailure,
    /// Never read.
    Unknown,
}

// === impl TagQuality ===

impl TagQuality {
    /// The quality named `name` (the image's [`Quality::as_str`] names); `Unknown` otherwise.
    pub fn from_name(name: &str) -> Self {
        match name {
            "good" => Self::Good,
            "stale" => Self::Stale,
            "not_defined" => Self::NotDefined,
            "off" => Self::Off,
            "out_of_range" => Self::OutOfRange,
            "rejected" => Self::Rejected,
            "comm_failure" => Self::CommFailure,
            _ => Self::Unknown,
        }
    }
}

impl From<Quality> for TagQuality {
    fn from(q: Quality) -> Self {
        match q {
            Quality::Good => Self::Good,
            Quality::OutOfRange => Self::OutOfRange,
            Quality::Off => Self::Off,
            Quality::NotDefined => Self::NotDefined,
            Quality::Rejected => Self::Rejected,
            Quality::Stale => Self::Stale,
            Quality::CommFailure => Self::CommFailure,
        }
    }
}

impl From<proto_core::profiles::Value> for ScalarValue {
    fn from(v: proto_core::profiles::Value) -> Self {
        use proto_core::profiles::Value;
        match v {
            Value::Int(i) => Self::Int(i),
            Value::UInt(u) => Self::UInt(u),
            Value::Float(f) => Self::Float(f),
            Value::Bool(b) => Self::Bool(b),
            Value::Text(t) => Self::Text(t),
        }
    }
}

impl From<ScalarValue> for proto_core::profiles::Value {
    fn from(v: ScalarValue) -> Self {
        match v {
            ScalarValue::Int(i) => Self::Int(i),
            ScalarValue::UInt(u) => Self::UInt(u),
            ScalarValue::Float(f) => Self::Float(f),
            ScalarValue::Bool(b) => Self::Bool(b),
            ScalarValue::Text(t) => Self::Text(t),
        }
    }
}

// === impl TagValue ===

impl TagValue {
    /// The value of `line/device/tag` from a reading of the tag directory; a value that is not
    /// live (stale, rejected, comm failure) is still shown, with its quality saying so.
    pub fn from_reading(
        line: &str,
        device: &str,
        tag: &str,
        writable: bool,
        reading: TagReading,
    ) -> Self {
        Self {
            line: line.to_owned(),
            device: device.to_owned(),
            tag: tag.to_owned(),
            value: Some(reading.value.into()),
            unit: reading.unit,
            quality: TagQuality::from_name(reading.quality),
            timestamp: Some(Timestamp(reading.timestamp)),
            writable,
            description: String::new(),
        }
    }
}

/// One tag's value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct TagValue {
    pub line: String,
    pub device: String,
    pub tag: String,
    /// raw x scale + offset, at the tag's places (`decimals`, else those scale and offset
    /// imply: 19.95, not 19.950000000000045); null when there is none (never read).
    pub value: Option<ScalarValue>,
    /// Engineering unit (`Hz`, `%`, `°C`), empty when none.
    pub unit: String,
    pub quality: TagQuality,
    /// When the value was read from the device.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timestamp: Option<Timestamp>,
    /// Whether `PUT` may write it.
    pub writable: bool,
    /// What the value is (the tag's `description`), absent when it has none.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub description: String,
}

/// The body of a tag write.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TagWrite {
    /// In the tag's engineering unit; the gateway writes raw = round((value - offset) / scale),
    /// and refuses a value the tag cannot hold exactly (422, with the nearest values).
    pub value: ScalarValue,
}

/// Filters of `GET /api/v1/tags`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct TagQuery {
    /// Only the tags of this line.
    pub line: Option<String>,
    /// Only the tags of devices of this name.
    pub device: Option<String>,
}

/// The RS232 signals of a line (000 5.4: DTR, DSR, RTS, CTS, DCD, RI).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct Signals {
    /// Data terminal ready (output).
    pub dtr: bool,
    /// Request to send (output).
    pub rts: bool,
    /// Data set ready (input).
    pub dsr: bool,
    /// Clear to send (input).
    pub cts: bool,
    /// Data carrier detect (input).
    pub dcd: bool,
    /// Ring indicator (input).
    pub ri: bool,
}

/// Outputs to set; an absent one is left as it is. The inputs cannot be set.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SignalsPatch {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dtr: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rts: Option<bool>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scalar_values_read_as_bits_integers_or_floats() {
        let v: TagWrite = serde_json::from_str(r#"{"value": 5}"#).unwrap();
        assert_eq!(v.value, ScalarValue::Int(5));
        let v: TagWrite = serde_json::from_str(r#"{"value": 5.5}"#).unwrap();
        assert_eq!(v.value, ScalarValue::Float(5.5));
        let v: TagWrite = serde_json::from_str(r#"{"value": true}"#).unwrap();
        assert_eq!(v.value.as_f64(), 1.0);
        // A text is for string tags; the tag decides whether it fits.
        let v: TagWrite = serde_json::from_str(r#"{"value": "5"}"#).unwrap();
        assert_eq!(v.value, ScalarValue::Text("5".into()));
        // Whole numbers beyond i64 stay exact, also when written out again.
        let v: TagWrite = serde_json::from_str(r#"{"value": 18446744073709551615}"#).unwrap();
        assert_eq!(v.value, ScalarValue::UInt(u64::MAX));
        assert_eq!(
            serde_json::to_string(&v).unwrap(),
            r#"{"value":18446744073709551615}"#
        );
        assert!(serde_json::from_str::<SignalsPatch>(r#"{"dsr": true}"#).is_err());
    }

    #[test]
    fn image_qualities_keep_their_names() {
        for q in [
            Quality::Good,
            Quality::OutOfRange,
            Quality::Off,
            Quality::NotDefined,
            Quality::Rejected,
            Quality::Stale,
            Quality::CommFailure,
        ] {
            let t = TagQuality::from(q);
            assert_eq!(TagQuality::from_name(q.as_str()), t);
            assert_eq!(serde_json::to_value(t).unwrap(), q.as_str());
        }
        assert_eq!(TagQuality::from_name("bogus"), TagQuality::Unknown);
    }
}
