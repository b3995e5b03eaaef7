//! RS232 modem signals of a serial port: read DTR, DSR, RTS, CTS, DCD and RI, set DTR and RTS.
//!
//! This is what the CP's FC 5 V24_STAT and FC 6 V24_SET do (000 5.4 "Zugriff auf
//! RS232-Begleitsignale"): V24_STAT reads the inputs and the outputs as they are set, V24_SET sets
//! DTR and RTS. The inputs (DSR, CTS, DCD, RI) are read from the port; the outputs (DTR, RTS)
//! cannot be read back through the serial library, so [`SignalState`] remembers what was last set
//! (`None` until the gateway sets one).
//!
//! 000 5.4 also says who may set an output: DTR with data flow control none, XON/XOFF or
//! RTS/CTS; RTS with none or XON/XOFF only (under RTS/CTS the driver drives it); neither under the
//! automatic V24 signal handling ("ist ein schreibender Zugriff mit dem FC 6 nicht möglich").
//! [`may_set`] encodes that table; the line refuses the rest with
//! [`SignalError::DrivenByDriver`]. "Nach dem Einschalten des CP sind alle Ausgangssignale
//! inaktiv": a line sets DTR and RTS off when it opens its port, where the port allows it.
//!
//! Where the port cannot do it the answer is a [`SignalError`] that names the port, the signal
//! and the reason: a pseudo-terminal has no modem lines at all (the kernel refuses the modem
//! ioctls with ENOTTY), and an RS422/RS485 line has no RS232 signals (000 5.4: the signals exist
//! on the RS232 interface only).

use std::fmt;

use tokio_serial::SerialPort;

/// One RS232 signal (000 5.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Signal {
    /// Data terminal ready (output).
    Dtr,
    /// Data set ready (input).
    Dsr,
    /// Request to send (output).
    Rts,
    /// Clear to send (input).
    Cts,
    /// Data carrier detect (input).
    Dcd,
    /// Ring indicator (input).
    Ri,
}

// === impl Signal ===

impl Signal {
    /// Every signal, in the order of V24_STAT's outputs.
    pub const ALL: [Self; 6] = [
        Self::Dtr,
        Self::Dsr,
        Self::Rts,
        Self::Cts,
        Self::Dcd,
        Self::Ri,
    ];

    /// The signal's short name ("DTR", ...).
    pub const fn name(self) -> &'static str {
        match self {
            Self::Dtr => "DTR",
            Self::Dsr => "DSR",
            Self::Rts => "RTS",
            Self::Cts => "CTS",
            Self::Dcd => "DCD",
            Self::Ri => "RI",
        }
    }
}

impl fmt::Display for Signal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An output the gateway may set (FC 6 V24_SET sets DTR and RTS only).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Output {
    /// Data terminal ready.
    Dtr,
    /// Request to send.
    Rts,
}

// === impl Output ===

impl Output {
    /// The signal this output is.
    pub const fn signal(self) -> Signal {
        match self {
            Self::Dtr => Signal::Dtr,
            Self::Rts => Signal::Rts,
        }
    }
}

/// A snapshot of the signals (V24_STAT). Inputs are read from the port; outputs are what the
/// gateway last set, `None` when it has not set them since the port was opened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ModemSignals {
    /// Data terminal ready, as last set.
    pub dtr: Option<bool>,
    /// Data set ready.
    pub dsr: bool,
    /// Request to send, as last set.
    pub rts: Option<bool>,
    /// Clear to send.
    pub cts: bool,
    /// Data carrier detect.
    pub dcd: bool,
    /// Ring indicator.
    pub ri: bool,
}

/// Why a signal could not be read or set.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SignalError {
    /// The port has no such signal or its driver refuses the request.
    #[error("port {path} cannot {action} {signal}: {reason}{hint}")]
    Unsupported {
        /// The device path.
        path: String,
        /// The signal.
        signal: Signal,
        /// "read" or "set".
        action: &'static str,
        /// What the operating system said.
        reason: String,
        /// A hint at the cause, e.g. " (a pseudo-terminal has no modem signals)".
        hint: &'static str,
    },
    /// The line is RS422 or RS485: there are no RS232 signals (000 5.4).
    #[error("line {line} is not an RS232 line: it has no modem signals")]
    NotRs232 {
        /// The line's name.
        line: String,
    },
    /// The line's data flow control drives this output (000 5.4, the table of the signals).
    #[error("{signal} of line {line} is driven by its {flow}; it cannot be set (000 5.4)")]
    DrivenByDriver {
        /// The line's name.
        line: String,
        /// The output.
        signal: Signal,
        /// The flow control, e.g. "RTS/CTS flow control".
        flow: &'static str,
    },
    /// The line only listens (a 3964(R) tap): it neither reads nor sets modem signals.
    #[error("line {line} only listens (3964r-tap): its modem signals are not used")]
    ListenOnly {
        /// The line's name.
        line: String,
    },
    /// The line's port is not open (it is being reopened after a failure).
    #[error("the port of line {line} is not open")]
    PortClosed {
        /// The line's name.
        line: String,
    },
    /// The line is stopping or stopped.
    #[error("line {line} is shutting down")]
    ShuttingDown {
        /// The line's name.
        line: String,
    },
}

/// What the gateway last set on DTR and RTS of an open port (they cannot be read back).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SignalState {
    /// DTR as last set.
    pub dtr: Option<bool>,
    /// RTS as last set.
    pub rts: Option<bool>,
}

/// Who drives the outputs of a line: its data flow control (000 5.4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum OutputOwner {
    /// No flow control or XON/XOFF: DTR and RTS are free to set.
    #[default]
    Free,
    /// RTS/CTS: the driver drives RTS; DTR is free.
    RtsCts,
    /// The automatic V24 signal handling drives both.
    AutoV24,
}

/// Whether FC 6 V24_SET may set `output` under `owner` (000 5.4: DTR "Datenfluss: keine,
/// XON/XOFF, RTS/CTS", RTS "Datenfluss: keine, XON/XOFF"; no write under the automatic handling).
/// `Err` names the flow control that drives it.
pub fn may_set(owner: OutputOwner, output: Output) -> Result<(), &'static str> {
    match (owner, output) {
        (OutputOwner::Free, _) | (OutputOwner::RtsCts, Output::Dtr) => Ok(()),
        (OutputOwner::RtsCts, Output::Rts) => Err("RTS/CTS flow control"),
        (OutputOwner::AutoV24, _) => Err("automatic V24 signal handling"),
    }
}

fn hint(path: &str, err: &tokio_serial::Error) -> &'static str {
    let is_pty = path.starts_with("/dev/pts/") || path.starts_with("/dev/pty");
    let not_a_tty = err.description.contains("Inappropriate ioctl");
    if is_pty {
        " (a pseudo-terminal has no modem signals)"
    } else if not_a_tty {
        " (the port's driver has no modem signals)"
    } else {
        ""
    }
}

fn unsupported(
    path: &str,
    signal: Signal,
    action: &'static str,
    err: &tokio_serial::Error,
) -> SignalError {
    SignalError::Unsupported {
        path: path.to_owned(),
        signal,
        action,
        reason: err.description.clone(),
        hint: hint(path, err),
    }
}

/// The answer for a port without modem lines (an in-process stream).
pub(crate) fn no_modem(path: &str, signal: Signal, action: &'static str) -> SignalError {
    SignalError::Unsupported {
        path: path.to_owned(),
        signal,
        action,
        reason: "the port has no modem lines".into(),
        hint: "",
    }
}

/// Reads one input of `port` (DSR, CTS, DCD, RI); an output (DTR, RTS) is answered from
/// `state`, or refused as unknown when it was never set.
///
/// # Errors
///
/// [`SignalError::Unsupported`] when the port's driver refuses the request.
pub fn read(
    port: &mut dyn SerialPort,
    path: &str,
    state: SignalState,
    signal: Signal,
) -> Result<bool, SignalError> {
    let result = match signal {
        Signal::Dsr => port.read_data_set_ready(),
        Signal::Cts => port.read_clear_to_send(),
        Signal::Dcd => port.read_carrier_detect(),
        Signal::Ri => port.read_ring_indicator(),
        Signal::Dtr | Signal::Rts => {
            let set = if signal == Signal::Dtr {
                state.dtr
            } else {
                state.rts
            };
            return set.ok_or_else(|| SignalError::Unsupported {
                path: path.to_owned(),
                signal,
                action: "read",
                reason: "an output cannot be read back and was not set since the port opened"
                    .into(),
                hint: "",
            });
        }
    };
    result.map_err(|err| unsupported(path, signal, "read", &err))
}

/// Reads every input of `port` and the outputs as last set (V24_STAT).
///
/// # Errors
///
/// The first input the port's driver refuses to read.
pub fn read_all(
    port: &mut dyn SerialPort,
    path: &str,
    state: SignalState,
) -> Result<ModemSignals, SignalError> {
    Ok(ModemSignals {
        dtr: state.dtr,
        dsr: read(port, path, state, Signal::Dsr)?,
        rts: state.rts,
        cts: read(port, path, state, Signal::Cts)?,
        dcd: read(port, path, state, Signal::Dcd)?,
        ri: read(port, path, state, Signal::Ri)?,
    })
}

/// Sets DTR or RTS of `port` (V24_SET) and records it in `state`.
///
/// # Errors
///
/// [`SignalError::Unsupported`] when the port's driver refuses; `state` is unchanged then.
pub fn set(
    port: &mut dyn SerialPort,
    path: &str,
    state: &mut SignalState,
    output: Output,
    on: bool,
) -> Result<(), SignalError> {
    let result = match output {
        Output::Dtr => port.write_data_terminal_ready(on),
        Output::Rts => port.write_request_to_send(on),
    };
    result.map_err(|err| unsupported(path, output.signal(), "set", &err))?;
    match output {
        Output::Dtr => state.dtr = Some(on),
        Output::Rts => state.rts = Some(on),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use tokio_serial::SerialStream;

    use super::*;

    impl Signal {
        /// Whether the gateway drives it (DTR, RTS); the others are inputs.
        const fn is_output(self) -> bool {
            matches!(self, Self::Dtr | Self::Rts)
        }
    }

    #[test]
    fn names_and_directions() {
        let names: Vec<&str> = Signal::ALL.iter().map(|s| s.name()).collect();
        assert_eq!(names, ["DTR", "DSR", "RTS", "CTS", "DCD", "RI"]);
        let outputs: Vec<Signal> = Signal::ALL.into_iter().filter(|s| s.is_output()).collect();
        assert_eq!(outputs, [Signal::Dtr, Signal::Rts]);
        assert_eq!(Output::Rts.signal(), Signal::Rts);
    }

    #[test]
    fn who_may_set_which_output() {
        assert_eq!(may_set(OutputOwner::Free, Output::Rts), Ok(()));
        assert_eq!(may_set(OutputOwner::RtsCts, Output::Dtr), Ok(()));
        assert_eq!(
            may_set(OutputOwner::RtsCts, Output::Rts),
            Err("RTS/CTS flow control")
        );
        assert!(may_set(OutputOwner::AutoV24, Output::Dtr).is_err());
        assert!(may_set(OutputOwner::AutoV24, Output::Rts).is_err());
    }

    #[tokio::test]
    async fn a_pty_refuses_modem_signals_with_a_clear_error() {
        let (_master, mut slave) = SerialStream::pair().expect("pty pair");
        let path = slave.name().unwrap_or_default();
        let mut state = SignalState::default();

        let err = read(&mut slave, &path, state, Signal::Cts).expect_err("a pty has no CTS");
        let text = err.to_string();
        assert!(
            text.starts_with(&format!("port {path} cannot read CTS: ")),
            "{text}"
        );
        assert!(
            text.ends_with("(a pseudo-terminal has no modem signals)"),
            "{text}"
        );
        assert!(read_all(&mut slave, &path, state).is_err());

        let err = set(&mut slave, &path, &mut state, Output::Dtr, true).expect_err("no DTR");
        assert!(matches!(
            err,
            SignalError::Unsupported {
                signal: Signal::Dtr,
                action: "set",
                ..
            }
        ));
        assert_eq!(
            state,
            SignalState::default(),
            "a refused set is not recorded"
        );

        // An output never set cannot be read back.
        let err = read(&mut slave, &path, state, Signal::Rts).expect_err("never set");
        assert!(err.to_string().contains("cannot be read back"), "{err}");
        // One that was set is answered from the record.
        state.rts = Some(true);
        assert_eq!(read(&mut slave, &path, state, Signal::Rts), Ok(true));
    }
}
