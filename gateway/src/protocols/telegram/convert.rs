//! From the configuration (`[lines.<name>]` with `protocol = "3964r"` or `"ascii"`) to the
//! settings of a telegram line.
//!
//! The mailbox follows the line's receive buffer: its depth is `receive_buffer`; its policy is
//! 3964(R) `overflow` (refuse: NAK, or drop-oldest), ASCII `prevent_overwrite` (on: the CP drops
//! the new telegram, or under XON/XOFF or RTS/CTS holds the partner back, 003 6.2.1; off: the
//! newest telegram replaces the held one, without an event).
//!
//! The port settings come from the serial section's one conversion (`protocols::start`), so that every
//! line opens its port the same way. The 3964(R), ASCII and 3964(R) tap sections start their lines
//! here ([`StartLine`]).

use proto_core::proc3964::{Params3964, Priority, Settings3964, Variant};
use proto_core::telegram::{
    AsciiParams, AsciiSettings, ConfigError, EndCriterion, FlowControl, Interface, DEFAULT_TX_CHUNK,
};

use proto_core::cpmem::MemoryLayout;

use super::{
    spawn_3964_tap_line, try_spawn_telegram_line, Tap3964LineSettings, TelegramLineSettings,
    TelegramProtocol,
};
use crate::config::{self as cfg, ConfigIssue, SerialConfig};
use crate::line::LineHandle;
use crate::mailbox::{AckMode, MailboxSettings, Overflow};
use crate::protocols::start::{port_settings, StartDeps, StartError, StartLine};
use crate::protocols::{
    AsciiConfig, LineConfig, Proc3964Config, Proc3964TapConfig, ProtocolConfig,
};
use crate::serial::PortSettings;

/// Why a line's configuration does not make a telegram line.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TelegramConfigError {
    /// The line speaks another protocol.
    #[error("line {0} is not a 3964(R) or ASCII line")]
    NotATelegramLine(String),
    /// The protocol engine refuses the parameters (the config check should have caught it).
    #[error("line {line}: {source}")]
    Invalid {
        /// The line.
        line: String,
        /// The parameter the engine refused.
        #[source]
        source: ConfigError,
    },
}

fn interface(serial: &SerialConfig) -> Interface {
    match serial.interface {
        cfg::Interface::Rs232 => Interface::Rs232,
        cfg::Interface::Rs422 => Interface::Rs422,
        cfg::Interface::Rs485 => Interface::Rs485,
    }
}

/// The engine parameters of a 3964(R) line.
///
/// # Errors
///
/// The parameter the engine refuses.
pub fn params_3964(serial: &SerialConfig, c: &Proc3964Config) -> Result<Params3964, ConfigError> {
    Params3964::try_new(Settings3964 {
        variant: if c.block_check {
            Variant::P3964R
        } else {
            Variant::P3964
        },
        priority: match c.priority {
            crate::protocols::Priority::High => Priority::High,
            crate::protocols::Priority::Low => Priority::Low,
        },
        baud: serial.baud.get(),
        interface: interface(serial),
        zvz: c.character_delay,
        qvz: c.ack_delay,
        setup_attempts: c.setup_attempts,
        transmission_attempts: c.transmission_attempts,
        max_len: c.max_telegram_len,
        receive_buffers: c.receive_buffer,
        send_queue: c.send_queue,
        hold_ack: false,
    })
}

/// The engine parameters of an ASCII line.
///
/// # Errors
///
/// The parameter the engine refuses.
pub fn params_ascii(serial: &SerialConfig, c: &AsciiConfig) -> Result<AsciiParams, ConfigError> {
    let end = match c.end_criterion {
        crate::protocols::EndCriterion::CharDelay => EndCriterion::CharacterDelay,
        crate::protocols::EndCriterion::FixedLength => EndCriterion::FixedLength(c.fixed_length),
        crate::protocols::EndCriterion::EndChars => EndCriterion::EndChars {
            first: c
                .end_chars
                .first()
                .copied()
                .unwrap_or(crate::protocols::DEFAULT_ASCII_END_CHARS[0]),
            second: c.end_chars.get(1).copied(),
        },
    };
    let flow = match c.flow_control {
        crate::protocols::FlowControl::None => FlowControl::None,
        crate::protocols::FlowControl::XonXoff => FlowControl::XonXoff {
            xon: c.xon_code,
            xoff: c.xoff_code,
        },
        crate::protocols::FlowControl::RtsCts => FlowControl::RtsCts,
        crate::protocols::FlowControl::AutoV24 => FlowControl::AutoV24 {
            output_wait: c.data_output_wait,
            rts_hold: c.rts_hold_time,
        },
    };
    AsciiParams::try_new(AsciiSettings {
        baud: serial.baud.get(),
        data_bits: serial.data_bits.get(),
        interface: interface(serial),
        end,
        zvz: c.character_delay,
        send_pause: c.send_pause,
        flow,
        flow_wait: c.xon_wait,
        receive_buffers: c.receive_buffer,
        prevent_overwrite: c.prevent_overwrite,
        send_queue: c.send_queue,
        tx_chunk: DEFAULT_TX_CHUNK,
    })
}

/// The engine parameters of a telegram line (3964(R) or ASCII); `None` for a line of another
/// protocol.
///
/// # Errors
///
/// The parameter the engine refuses.
pub fn engine_protocol(line: &LineConfig) -> Option<Result<TelegramProtocol, ConfigError>> {
    match &line.protocol {
        ProtocolConfig::Proc3964(c) => {
            Some(params_3964(&line.serial, c).map(TelegramProtocol::P3964))
        }
        ProtocolConfig::Ascii(c) => {
            Some(params_ascii(&line.serial, c).map(TelegramProtocol::Ascii))
        }
        _ => None,
    }
}

// === impl TelegramLineSettings (from the configuration) ===

impl TelegramLineSettings {
    /// The settings of the configured line `name` on `port` (the runtime's port settings of the
    /// line's serial section). Diagnostic depth and reopen back-off keep their defaults; set them
    /// from the gateway section.
    ///
    /// # Errors
    ///
    /// The line is no telegram line, or its engine refuses a parameter.
    pub fn from_config(
        name: &str,
        line: &LineConfig,
        port: PortSettings,
    ) -> Result<Self, TelegramConfigError> {
        use crate::protocols::{FlowControl as Flow, Overflow3964};
        let invalid = |source| TelegramConfigError::Invalid {
            line: name.to_owned(),
            source,
        };
        let (protocol, overflow, depth, max_len, send_queue) = match &line.protocol {
            ProtocolConfig::Proc3964(c) => {
                let overflow = match c.overflow {
                    Overflow3964::Refuse => Overflow::Refuse,
                    Overflow3964::DropOldest => Overflow::DropOldest,
                };
                let params = params_3964(&line.serial, c).map_err(invalid)?;
                let protocol = TelegramProtocol::P3964(params);
                (
                    protocol,
                    overflow,
                    c.receive_buffer,
                    c.max_telegram_len,
                    c.send_queue,
                )
            }
            ProtocolConfig::Ascii(c) => {
                // Only XON/XOFF and RTS/CTS can hold the partner back (003 6.2.1); under the
                // automatic V24 handling "Bei Überlauf des Empfangspuffers erfolgt keine Reaktion
                // des CP" (000 5.4).
                let overflow = match (c.prevent_overwrite, c.flow_control) {
                    (false, _) => Overflow::Overwrite,
                    (true, Flow::XonXoff | Flow::RtsCts) => Overflow::Refuse,
                    (true, Flow::None | Flow::AutoV24) => Overflow::DropNew,
                };
                let protocol =
                    TelegramProtocol::Ascii(params_ascii(&line.serial, c).map_err(invalid)?);
                (
                    protocol,
                    overflow,
                    c.receive_buffer,
                    c.max_telegram_len,
                    c.send_queue,
                )
            }
            _ => return Err(TelegramConfigError::NotATelegramLine(name.to_owned())),
        };
        let mut settings = Self::new(name, port, protocol);
        settings.mailbox = MailboxSettings {
            queue_depth: usize::from(depth),
            overflow,
            ack: line.ack().map_or(AckMode::Explicit, mailbox_ack),
        };
        settings.max_len = usize::from(max_len);
        settings.send_queue = usize::from(send_queue);
        settings.unit_id = line.unit_id();
        settings.sends = line.sends();
        settings.journal = line.journal().map(ToOwned::to_owned);
        Ok(settings)
    }
}

// === impl StartLine for the telegram sections ===

/// The 3964(R) and ASCII sections start alike: their settings come from the line's section
/// ([`TelegramLineSettings::from_config`]).
macro_rules! start_telegram_sections {
    ($($section:ty),+) => {$(
        impl StartLine for $section {
            fn start(
                &self,
                name: &str,
                line: &LineConfig,
                deps: &StartDeps<'_>,
            ) -> Result<LineHandle, StartError> {
                start_telegram_line(name, line, deps)
            }

            fn start_issues(
                &self,
                name: &str,
                line: &LineConfig,
                _layout: Option<&MemoryLayout>,
            ) -> Vec<ConfigIssue> {
                telegram_issues(name, line)
            }
        }
    )+};
}

start_telegram_sections!(Proc3964Config, AsciiConfig);

/// Starts a telegram line with the gateway-wide settings: the diagnostic depth and the
/// acknowledgement default, which needs the whole configuration.
fn start_telegram_line(
    name: &str,
    line: &LineConfig,
    deps: &StartDeps<'_>,
) -> Result<LineHandle, StartError> {
    let settings = TelegramLineSettings::from_config(name, line, port_settings(&line.serial));
    let mut settings = settings.map_err(|e| StartError(format!("line {name}: {e}")))?;
    settings.diag_depth = usize::from(deps.gateway.diag_buffer_depth);
    settings.metrics = Some(deps.metrics.clone());
    settings.mailbox.ack = mailbox_ack(crate::protocols::ack_mode(deps.zenoh_on, line));
    settings.carried = deps.carried.clone();
    try_spawn_telegram_line(settings, deps.token.clone())
        .map_err(|e| StartError(format!("line {name}: {e}")))
}

/// What would keep a telegram line from starting: the parameter its engine refuses. Its journal
/// is opened by the start check of every door (`app::check::start_issues`), which knows whether
/// a REST change may name the file at all.
fn telegram_issues(name: &str, line: &LineConfig) -> Vec<ConfigIssue> {
    TelegramLineSettings::from_config(name, line, port_settings(&line.serial))
        .err()
        .map(|e| ConfigIssue {
            path: format!("lines.{name}"),
            message: e.to_string(),
        })
        .into_iter()
        .collect()
}

impl StartLine for Proc3964TapConfig {
    fn start(
        &self,
        name: &str,
        line: &LineConfig,
        deps: &StartDeps<'_>,
    ) -> Result<LineHandle, StartError> {
        let variant = if self.block_check {
            Variant::P3964R
        } else {
            Variant::P3964
        };
        let mut settings =
            Tap3964LineSettings::new(name, port_settings(&line.serial), &self.port_b, variant);
        settings.tap.zvz = self.character_delay;
        settings.tap.qvz = self.ack_delay;
        settings.tap.max_len = self.max_telegram_len;
        settings.mailbox_depth = usize::from(self.receive_buffer);
        settings.unit_id = self.unit_id;
        settings.diag_depth = usize::from(deps.gateway.diag_buffer_depth);
        settings.metrics = Some(deps.metrics.clone());
        Ok(spawn_3964_tap_line(settings, deps.token.clone()))
    }
}

/// The mailbox's [`AckMode`] for a line's `ack`. `from_config` takes an unset `ack` as
/// explicit; the gateway's start resolves the default with [`crate::protocols::ack_mode`], which needs the
/// whole configuration.
pub fn mailbox_ack(ack: cfg::AckConfig) -> AckMode {
    match ack {
        cfg::AckConfig::OnPublish => AckMode::OnPublish,
        cfg::AckConfig::Explicit => AckMode::Explicit,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn port() -> PortSettings {
        PortSettings::new("/dev/null", 9600)
    }

    fn line(config: &crate::plant::Config, name: &str) -> LineConfig {
        config.lines.get(name).cloned().expect("demo line")
    }

    #[test]
    fn the_demo_lines_make_telegram_lines_with_the_manuals_defaults() {
        let demo = crate::plant::demo();
        let r3964 = TelegramLineSettings::from_config("r3964", &line(&demo, "r3964"), port())
            .expect("3964r line");
        let TelegramProtocol::P3964(p) = &r3964.protocol else {
            panic!("3964R expected");
        };
        let s = p.settings();
        assert_eq!((s.variant, s.priority), (Variant::P3964R, Priority::High));
        assert_eq!(
            (s.zvz.as_millis(), s.qvz.as_millis(), s.setup_attempts),
            (220, 2000, 6)
        );
        assert_eq!(r3964.max_len, 250);
        assert_eq!(
            r3964.mailbox,
            MailboxSettings {
                queue_depth: 250,
                overflow: Overflow::Refuse,
                ack: AckMode::Explicit,
            }
        );

        let ascii = TelegramLineSettings::from_config("ascii", &line(&demo, "ascii"), port())
            .expect("ascii line");
        let TelegramProtocol::Ascii(p) = &ascii.protocol else {
            panic!("ASCII expected");
        };
        assert_eq!(
            p.settings().end,
            EndCriterion::EndChars {
                first: 0x03,
                second: None
            }
        );
        assert_eq!(ascii.mailbox.overflow, Overflow::DropNew);
        assert_eq!(ascii.max_len, 1024);

        let drive = line(&demo, "drive");
        assert_eq!(
            TelegramLineSettings::from_config("drive", &drive, port()).unwrap_err(),
            TelegramConfigError::NotATelegramLine("drive".into())
        );
    }
}
