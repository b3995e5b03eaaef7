//! Label values of the metric families, each from a closed set.
//!
//! No label carries a value a client or a device chooses freely: function codes outside the known
//! set count as `"other"`, exception codes outside the Modbus set as `"exception_other"`, and the
//! remaining labels are enums. The free-text labels `line` and `device` come from the
//! configuration, so their number is bounded by it.

use proto_core::modbus::pdu::ExceptionCode;

/// A label of a closed set, written once: the enum (each variant with its doc and its label
/// value), `ALL` (every value, for pre-creating series) and `as_str` (the label value).
macro_rules! label_enum {
    (
        $(#[doc = $doc:literal])*
        pub enum $name:ident {
            $($(#[doc = $vdoc:literal])* $variant:ident = $label:literal,)+
        }
    ) => {
        $(#[doc = $doc])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        pub enum $name {
            $($(#[doc = $vdoc])* $variant,)+
        }

        impl $name {
            /// Every value, for pre-creating series.
            pub const ALL: [Self; [$($label),+].len()] = [$(Self::$variant),+];

            /// The label value.
            pub const fn as_str(self) -> &'static str {
                match self {
                    $(Self::$variant => $label,)+
                }
            }
        }
    };
}
pub(crate) use label_enum;

label_enum! {
    /// Direction of telegrams and bytes on a serial line, as seen from the gateway.
    pub enum Direction {
        /// Received from the partner or device.
        Rx = "rx",
        /// Sent by the gateway.
        Tx = "tx",
    }
}

/// The outcome of one Modbus request, on a serial line or from a Modbus TCP client.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RequestResult {
    /// A normal response.
    Ok,
    /// An exception response with this code.
    Exception(ExceptionCode),
    /// No reply within the reply monitoring time (003 7.2, event 08 30h).
    Timeout,
    /// A reply that could not be used (wrong slave, CRC, length, echo: 003 7.2, 08 31h and
    /// 0E 50h..0E 58h), or a local failure (port lost, queue closed).
    Error,
}

/// Exception codes with a label of their own: the codes of the Modbus Application Protocol
/// V1.1b3 (7, "MODBUS Exception Responses") plus 07, which the CP 341 reports as 0E 67h (003 7.2).
const EXCEPTION_LABELS: [(u8, &str); 10] = [
    (0x01, "exception_01"),
    (0x02, "exception_02"),
    (0x03, "exception_03"),
    (0x04, "exception_04"),
    (0x05, "exception_05"),
    (0x06, "exception_06"),
    (0x07, "exception_07"),
    (0x08, "exception_08"),
    (0x0A, "exception_0A"),
    (0x0B, "exception_0B"),
];

/// The `result` label of a code outside [`EXCEPTION_LABELS`].
const EXCEPTION_OTHER: &str = "exception_other";

// === impl RequestResult ===

impl RequestResult {
    /// The `result` label value: `ok`, `exception_NN` (two upper-case hex digits),
    /// `exception_other`, `timeout` or `error`.
    pub fn as_str(self) -> &'static str {
        Self::label_at(self.index())
    }

    /// How many `result` labels there are: [`Self::index`] is below it.
    pub const COUNT: usize = EXCEPTION_LABELS.len() + 4;

    /// The position of the result's label among the [`Self::COUNT`] labels (for counters kept
    /// in an array, one per label).
    pub fn index(self) -> usize {
        let other = EXCEPTION_LABELS.len() + 1;
        match self {
            Self::Ok => 0,
            Self::Exception(code) => {
                let code = u8::from(code);
                EXCEPTION_LABELS
                    .iter()
                    .position(|(known, _)| *known == code)
                    .map_or(other, |at| at + 1)
            }
            Self::Timeout => other + 1,
            Self::Error => other + 2,
        }
    }

    /// The label at `index` (see [`Self::index`]).
    pub fn label_at(index: usize) -> &'static str {
        let exceptions = EXCEPTION_LABELS.len();
        match index {
            0 => "ok",
            i if i <= exceptions => EXCEPTION_LABELS
                .get(i - 1)
                .map_or(EXCEPTION_OTHER, |(_, label)| label),
            i if i == exceptions + 1 => EXCEPTION_OTHER,
            i if i == exceptions + 2 => "timeout",
            _ => "error",
        }
    }
}

/// Function codes with a label of their own: every function the gateway speaks as master or
/// server (003 6.4.2 "Function codes", 6.4.6 for the slave; 002 for 23 = 17h and 43 = 2Bh), the
/// 32-bit register variants of the Modbus master ASCII (003 6.4: bit 6 set, 43h, 46h, 50h), and the
/// diagnostics functions 0Bh/0Ch of the Modbus specification.
const FUNCTION_LABELS: [(u8, &str); 18] = [
    (0x01, "01"),
    (0x02, "02"),
    (0x03, "03"),
    (0x04, "04"),
    (0x05, "05"),
    (0x06, "06"),
    (0x07, "07"),
    (0x08, "08"),
    (0x0B, "0B"),
    (0x0C, "0C"),
    (0x0F, "0F"),
    (0x10, "10"),
    (0x11, "11"),
    (0x17, "17"),
    (0x2B, "2B"),
    (0x43, "43"),
    (0x46, "46"),
    (0x50, "50"),
];

/// The `function` label of a code outside [`FUNCTION_LABELS`].
const FUNCTION_OTHER: &str = "other";

/// How many `function` labels there are: [`function_index`] is below it.
pub const FUNCTION_COUNT: usize = FUNCTION_LABELS.len() + 1;

/// The position of the function's label among the [`FUNCTION_COUNT`] labels (`other` last).
pub fn function_index(function: u8) -> usize {
    FUNCTION_LABELS
        .iter()
        .position(|(known, _)| *known == function)
        .unwrap_or(FUNCTION_LABELS.len())
}

/// The `function` label at `index` (see [`function_index`]).
pub fn function_label_at(index: usize) -> &'static str {
    FUNCTION_LABELS
        .get(index)
        .map_or(FUNCTION_OTHER, |(_, label)| label)
}

/// The `function` label value of a request's function code: two upper-case hex digits (`"03"`,
/// `"2B"`) for the known functions, `"other"` for the rest (a code with bit 7 set included: that is
/// no request). Pass the request's code, also when the answer was an exception.
pub fn function_label(function: u8) -> &'static str {
    function_label_at(function_index(function))
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use super::*;

    #[test]
    fn function_labels_are_two_hex_digits_or_other() {
        let labels: BTreeSet<_> = (0..=u8::MAX).map(function_label).collect();
        assert_eq!(labels.len(), FUNCTION_LABELS.len() + 1);
        assert_eq!(function_label(0x03), "03");
        assert_eq!(function_label(0x83), "other", "no request has bit 7 set");
        assert_eq!(function_label(0x2B), "2B");
        assert_eq!(function_label(0x42), "other");
        for (code, label) in FUNCTION_LABELS {
            assert_eq!(label, format!("{code:02X}"));
        }
    }

    #[test]
    fn result_labels_are_bounded() {
        let labels: BTreeSet<_> = (0..=u8::MAX)
            .map(|code| RequestResult::Exception(ExceptionCode::from(code)).as_str())
            .collect();
        assert_eq!(labels.len(), EXCEPTION_LABELS.len() + 1);
        let gateway_target = ExceptionCode::GatewayTargetFailedToRespond;
        assert_eq!(
            RequestResult::Exception(gateway_target).as_str(),
            "exception_0B"
        );
        assert_eq!(
            RequestResult::Exception(ExceptionCode::Other(0x09)).as_str(),
            "exception_other"
        );
        assert_eq!(RequestResult::Ok.as_str(), "ok");
        assert_eq!(RequestResult::Timeout.as_str(), "timeout");
        assert_eq!(RequestResult::Error.as_str(), "error");
        for (code, label) in EXCEPTION_LABELS {
            assert_eq!(label, format!("exception_{code:02X}"));
        }
    }
}
