//! What every protocol's config section answers for its line, whatever the protocol: the seam
//! between the configuration's common checks and views (ports, unit ids, devices, telegrams) and
//! the sections in the protocols' folders (`protocols/<protocol>/config.rs`), which implement
//! it. A leaf: it knows none of the sections.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::check::{Check, Line};
use super::device::DeviceConfig;

/// What a protocol's config section tells the rest of the configuration about its line. Each
/// section implements it in its protocol's folder (`protocols/<protocol>/config.rs`); the
/// `section` method of `ProtocolConfig`, made by the protocols' table, is the one place that lists
/// them. Every answer has the default of a line without that part. Its checks that span keys or
/// need the serial settings (timing minimums by baud rate, the protocol against the interface)
/// are its [`Check`] in the [`Line`] scope, in the same file.
pub(crate) trait ProtocolSection: for<'a> Check<Line<'a>> {
    /// The devices the line polls or listens to.
    fn devices(&self) -> Option<&BTreeMap<String, DeviceConfig>> {
        None
    }

    /// The devices, to change them.
    fn devices_mut(&mut self) -> Option<&mut BTreeMap<String, DeviceConfig>> {
        None
    }

    /// The second receive port (`port_b`).
    fn second_port(&self) -> Option<&str> {
        None
    }

    /// The unit ids the line forwards transparently (a Modbus master line with
    /// `transparent = true`); `None` otherwise.
    fn transparent_units(&self) -> Option<std::ops::RangeInclusive<u8>> {
        None
    }

    /// The Modbus TCP unit id of the line itself (slave memory or telegram mailbox).
    fn unit_id(&self) -> Option<u8> {
        None
    }

    /// The mailbox keys of a line that exchanges telegrams with a partner.
    fn telegrams(&self) -> Option<TelegramKeys<'_>> {
        None
    }
}

/// The mailbox keys of a telegram line, as [`ProtocolSection::telegrams`] answers them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TelegramKeys<'a> {
    /// `sends`.
    pub sends: bool,
    /// `ack`, if set.
    pub ack: Option<AckConfig>,
    /// `journal`, if set.
    pub journal: Option<&'a Path>,
}

/// Who acknowledges the received telegrams of a line (`ack`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AckConfig {
    /// A client acknowledges each telegram (Modbus TCP register 600, REST, zenoh `<line>/ack`).
    Explicit,
    /// The gateway acknowledges a telegram once zenoh took its publication on `<line>/rx`.
    OnPublish,
}
