//! Schneider Altivar 61/71 with integrated Modbus (seed manual 002).
//!
//! Addresses are the drive's logical addresses ("W3201" is register 3201), sent on the wire as
//! they are. Facts from 002 carry the section name; facts the seed does not give (the meaning of
//! ETA and CMD bits, the units of LCR, ULN, OTR, THD, THR) follow the Drivecom profile (CiA 402)
//! and the ATV61/71 communication parameters guide, and say so.

use core::time::Duration;

use super::{
    BitField, DataType, DeviceProfile, KeepAlive, Quality, ReadWriteLimits, Registered,
    RequestLimits, ScannerSpec, SpecialValues, Tag,
};
use crate::modbus::pdu::FunctionCode;

/// The word a parameter that does not exist or is protected reads as (002 "Lesen nicht
/// vorhandener oder geschützter Parameter": 16#8000; only when every word of a request is so does
/// the drive answer exception 02).
pub const NOT_AVAILABLE: u16 = 0x8000;

/// The drive's slave address in the demo and the simulator (002 "Beispiel 1": slave 2).
pub const DEFAULT_ADDRESS: u8 = 2;

/// 002 "Modbus-Funktionen": FC 03 reads at most 63 words.
pub const MAX_READ: u16 = 63;
/// 002 "Modbus-Funktionen": FC 16 writes at most 61 words.
pub const MAX_WRITE: u16 = 61;
/// 002 "Modbus-Funktionen": FC 23 reads at most 20 words.
pub const MAX_RW_READ: u16 = 20;
/// 002 "Modbus-Funktionen": FC 23 writes at most 20 words.
pub const MAX_RW_WRITE: u16 = 20;
/// The longest RTU ADU: 002 is silent, Modbus over Serial Line V1.02 2.5.1.1 gives 256 bytes.
pub const MAX_ADU_LEN: usize = 256;

/// 002 "Modbus-Funktionen": 03, 06, 08, 16, 23, 43.
pub const FUNCTIONS: [FunctionCode; 6] = [
    FunctionCode::READ_HOLDING_REGISTERS,
    FunctionCode::WRITE_SINGLE_REGISTER,
    FunctionCode::DIAGNOSTICS,
    FunctionCode::WRITE_MULTIPLE_REGISTERS,
    FunctionCode::READ_WRITE_MULTIPLE_REGISTERS,
    FunctionCode::ENCAPSULATED_INTERFACE,
];

/// 002 "Diagnose: Funktion 8": the sub-functions the drive knows (echo, clear counters, CRC error
/// counter, messages for this slave).
pub const DIAGNOSTIC_SUB_FUNCTIONS: [u16; 4] = [0x00, 0x0A, 0x0C, 0x0E];

/// 002 "Konfiguration Management Kommunikationsfehler": without a Modbus request for 10 s (the
/// default time-out) the drive raises the Modbus fault SLF.
pub const COMMUNICATION_TIMEOUT: Duration = Duration::from_secs(10);

/// How often the gateway rewrites CMD: half the time-out, so that one lost write is survived.
pub const KEEP_ALIVE_PERIOD: Duration = Duration::from_secs(5);

/// Switching frequency SFr (002 "Beispiel 1": W3102 = 16#0028 = 4 kHz, so 0.1 kHz).
pub const SFR: u16 = 3102;
/// Maximum output frequency tFr (002 "Beispiel 1": W3103 = 16#0258 = 60 Hz, so 0.1 Hz).
pub const TFR: u16 = 3103;
/// High speed HSP (002 "Beispiel 1": W3104 = 16#01F4 = 50 Hz, so 0.1 Hz).
pub const HSP: u16 = 3104;
/// Low speed LSP (002 "Beispiel 1": W3105 = 0 Hz).
pub const LSP: u16 = 3105;
/// Status word ETA, read-only (002 "Ausnahmeantworten": a write answers exception 04).
pub const ETA: u16 = 3201;
/// Motor current LCR (002 "Konfiguration der Überwachungsparameter": 3204).
pub const LCR: u16 = 3204;
/// Motor torque OTR (002: 3205).
pub const OTR: u16 = 3205;
/// Mains voltage ULN (002 "Kommunikationsscanner": W3207).
pub const ULN: u16 = 3207;
/// Drive thermal state THD (002 "Kommunikationsscanner": W3209).
pub const THD: u16 = 3209;
/// CRC errors on Modbus network M1EC (002 "Modbus-Zähler": 6010, stops at 65535).
pub const M1EC: u16 = 6010;
/// Frames on Modbus network M1CT (002 "Modbus-Zähler": 6011, modulo 65536).
pub const M1CT: u16 = 6011;
/// CRC errors on Modbus HMI M2EC (002 "Modbus-Zähler": 6030).
pub const M2EC: u16 = 6030;
/// Frames on Modbus HMI M2CT (002 "Modbus-Zähler": 6031).
pub const M2CT: u16 = 6031;
/// Last fault LFT (002 "Konfiguration der Überwachungsparameter": 7121).
pub const LFT: u16 = 7121;
/// The address 002 uses as its example of a parameter that does not exist (W8400).
pub const MISSING_EXAMPLE: u16 = 8400;
/// Profile CHCF (002 "Lesen nicht vorhandener ...": W8401, 16#0003 = I/O mode).
pub const CHCF: u16 = 8401;
/// Command copy COP (002: W8402, 16#0002 = copy of the command word).
pub const COP: u16 = 8402;
/// Control word CMD (002 "Kommunikationsscanner": W8501).
pub const CMD: u16 = 8501;
/// Speed reference LFRD in rpm (002 "Kommunikationsscanner": W8602).
pub const LFRD: u16 = 8602;
/// Output speed RFRD in rpm (002 "Kommunikationsscanner": W8604).
pub const RFRD: u16 = 8604;
/// Acceleration ramp ACC (002 "Schreiben eines Ausgangswortes": W9001).
pub const ACC: u16 = 9001;
/// Deceleration ramp DEC (002 "Schreiben von N Ausgangswörtern": W9002).
pub const DEC: u16 = 9002;
/// Motor thermal state THR (002 "Kommunikationsscanner": W9630).
pub const THR: u16 = 9630;

/// Scanner input addresses NMA1..NMA8 (002 "Kommunikationsscanner": W12701..W12708).
pub const NMA: [u16; 8] = [12701, 12702, 12703, 12704, 12705, 12706, 12707, 12708];
/// Scanner output addresses NCA1..NCA8 (W12721..W12728).
pub const NCA: [u16; 8] = [12721, 12722, 12723, 12724, 12725, 12726, 12727, 12728];
/// Scanner input values NM1..NM8 (W12741..W12748 = 16#31C5..16#31CC): the words NMA1..8 name.
pub const NM: [u16; 8] = [12741, 12742, 12743, 12744, 12745, 12746, 12747, 12748];
/// Scanner output values NC1..NC8 (W12761..W12768 = 16#31D9..16#31E0): written to the words
/// NCA1..8 name (002 prints "W12 708" as the end, a misprint for W12768).
pub const NC: [u16; 8] = [12761, 12762, 12763, 12764, 12765, 12766, 12767, 12768];
/// Factory assignment of NMA1..8 (002 "Konfiguration des Kommunikationsscanners": ETA, RFRD).
pub const NMA_DEFAULT: [u16; 8] = [ETA, RFRD, 0, 0, 0, 0, 0, 0];
/// Factory assignment of NCA1..8 (002: CMD, LFRD).
pub const NCA_DEFAULT: [u16; 8] = [CMD, LFRD, 0, 0, 0, 0, 0, 0];

/// ETA bits (Drivecom profile, CiA 402 status word; 002 "Beispiel für die Anzeige des
/// Kommunikationsscanners" reads 16#8637 as operation enabled, reverse, reference reached).
pub mod eta {
    /// Ready to switch on.
    pub const READY_TO_SWITCH_ON: u16 = 1 << 0;
    /// Switched on.
    pub const SWITCHED_ON: u16 = 1 << 1;
    /// Operation enabled.
    pub const OPERATION_ENABLED: u16 = 1 << 2;
    /// Fault.
    pub const FAULT: u16 = 1 << 3;
    /// Voltage enabled (power section supplied).
    pub const VOLTAGE_ENABLED: u16 = 1 << 4;
    /// Quick stop, active at 0.
    pub const QUICK_STOP: u16 = 1 << 5;
    /// Switch on disabled.
    pub const SWITCH_ON_DISABLED: u16 = 1 << 6;
    /// Alarm (warning).
    pub const ALARM: u16 = 1 << 7;
    /// Remote: commands come from the network.
    pub const REMOTE: u16 = 1 << 9;
    /// Reference (target) reached.
    pub const TARGET_REACHED: u16 = 1 << 10;
    /// Internal limit active.
    pub const INTERNAL_LIMIT: u16 = 1 << 11;
    /// Stop by the STOP key.
    pub const STOP_KEY: u16 = 1 << 14;
    /// Direction: 1 = reverse.
    pub const REVERSE: u16 = 1 << 15;
}

/// CMD bits (Drivecom profile, CiA 402 control word; 002 "Beispiel für die Anzeige des
/// Kommunikationsscanners": 16#000F = command "operation enabled" (start)).
pub mod cmd {
    /// Switch on.
    pub const SWITCH_ON: u16 = 1 << 0;
    /// Enable voltage.
    pub const ENABLE_VOLTAGE: u16 = 1 << 1;
    /// Quick stop, active at 0.
    pub const QUICK_STOP: u16 = 1 << 2;
    /// Enable operation.
    pub const ENABLE_OPERATION: u16 = 1 << 3;
    /// Fault reset, on the rising edge.
    pub const FAULT_RESET: u16 = 1 << 7;
    /// Halt.
    pub const HALT: u16 = 1 << 8;
    /// Direction: 1 = reverse.
    pub const REVERSE: u16 = 1 << 11;
    /// Shutdown: to "ready to switch on".
    pub const SHUTDOWN: u16 = 0x0006;
    /// Switch on: to "switched on".
    pub const SWITCH_ON_COMMAND: u16 = 0x0007;
    /// Enable operation: to "operation enabled" (run).
    pub const ENABLE_OPERATION_COMMAND: u16 = 0x000F;
    /// Disable voltage: to "switch on disabled".
    pub const DISABLE_VOLTAGE: u16 = 0x0000;
}

/// The Drivecom state an ETA word shows (CiA 402 state masks).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DriveState {
    /// Initialising.
    NotReadyToSwitchOn,
    /// Power on, no command yet, or after "disable voltage".
    SwitchOnDisabled,
    /// After "shutdown".
    ReadyToSwitchOn,
    /// After "switch on".
    SwitchedOn,
    /// Running (after "enable operation").
    OperationEnabled,
    /// Stopping on a quick stop.
    QuickStopActive,
    /// Stopping on a fault.
    FaultReactionActive,
    /// Faulted; needs a fault reset.
    Fault,
}

// === impl DriveState ===

impl DriveState {
    /// The state an ETA word shows.
    pub const fn from_eta(eta: u16) -> Self {
        match eta & 0x4F {
            0x40 => return Self::SwitchOnDisabled,
            0x0F => return Self::FaultReactionActive,
            0x08 => return Self::Fault,
            0x00 => return Self::NotReadyToSwitchOn,
            _ => {}
        }
        match eta & 0x6F {
            0x21 => Self::ReadyToSwitchOn,
            0x23 => Self::SwitchedOn,
            0x27 => Self::OperationEnabled,
            0x07 => Self::QuickStopActive,
            _ => Self::NotReadyToSwitchOn,
        }
    }

    /// The low bits of ETA in this state (bits 0..6, quick stop bit set except in quick stop).
    pub const fn eta_bits(self) -> u16 {
        match self {
            Self::NotReadyToSwitchOn => 0x0000,
            Self::SwitchOnDisabled => 0x0040,
            Self::ReadyToSwitchOn => 0x0021,
            Self::SwitchedOn => 0x0023,
            Self::OperationEnabled => 0x0027,
            Self::QuickStopActive => 0x0007,
            Self::FaultReactionActive => 0x000F,
            Self::Fault => 0x0008,
        }
    }
}

fn eta_bits() -> Vec<BitField> {
    [
        ("ready_to_switch_on", 0),
        ("switched_on", 1),
        ("operation_enabled", 2),
        ("fault", 3),
        ("voltage_enabled", 4),
        ("quick_stop_off", 5),
        ("switch_on_disabled", 6),
        ("alarm", 7),
        ("remote", 9),
        ("target_reached", 10),
        ("internal_limit", 11),
        ("stop_key", 14),
        ("reverse", 15),
    ]
    .into_iter()
    .map(|(name, bit)| BitField::flag(name, bit))
    .collect()
}

fn cmd_bits() -> Vec<BitField> {
    [
        ("switch_on", 0),
        ("enable_voltage", 1),
        ("quick_stop_off", 2),
        ("enable_operation", 3),
        ("fault_reset", 7),
        ("halt", 8),
        ("reverse", 11),
    ]
    .into_iter()
    .map(|(name, bit)| BitField::flag(name, bit))
    .collect()
}

/// The drive's tags.
///
/// Units: SFr 0.1 kHz, tFr/HSP/LSP 0.1 Hz, RFRD/LFRD rpm (002 "Beispiel 1" and the scanner
/// display example). ACC/DEC in 0.1 s: the ramp unit follows the ramp increment INR, factory
/// setting 0.1 s (ATV61/71 programming manual); note that 002's FC 06 and FC 16 examples describe
/// their values (13, 20, 30) as seconds. LCR 0.1 A, ULN 0.1 V, OTR/THD/THR in % (ATV61/71
/// communication parameters guide; 002 names the parameters but gives no units). Write ranges
/// are plausible bounds where 002 gives none.
pub fn tags() -> Vec<Tag> {
    let mut tags = parameter_tags();
    tags.extend(scanner_tags());
    tags
}

/// The drive's parameters and measurements (see [`tags`] for their units).
fn parameter_tags() -> Vec<Tag> {
    use DataType::{I16, U16};
    vec![
        Tag::holding("SFr", SFR, U16)
            .describe("switching frequency")
            .fix_point(1)
            .unit("kHz")
            .writable_within(10, 160),
        Tag::holding("tFr", TFR, U16)
            .describe("maximum output frequency")
            .fix_point(1)
            .unit("Hz")
            .writable_within(100, 16000),
        Tag::holding("HSP", HSP, U16)
            .describe("high speed")
            .fix_point(1)
            .unit("Hz")
            .writable_within(0, 16000),
        Tag::holding("LSP", LSP, U16)
            .describe("low speed")
            .fix_point(1)
            .unit("Hz")
            .writable_within(0, 16000),
        Tag::holding("ETA", ETA, U16)
            .describe("status word")
            .bits(eta_bits()),
        Tag::holding("LCR", LCR, U16)
            .describe("motor current")
            .fix_point(1)
            .unit("A"),
        Tag::holding("OTR", OTR, I16)
            .describe("motor torque")
            .unit("%"),
        Tag::holding("ULN", ULN, U16)
            .describe("mains voltage")
            .fix_point(1)
            .unit("V"),
        Tag::holding("THD", THD, U16)
            .describe("drive thermal state")
            .unit("%"),
        Tag::holding("M1EC", M1EC, U16).describe("CRC errors, Modbus network"),
        Tag::holding("M1CT", M1CT, U16).describe("frames, Modbus network"),
        Tag::holding("LFT", LFT, U16).describe("last fault"),
        Tag::holding("CHCF", CHCF, U16)
            .describe("profile (1 not separate, 2 separate, 3 I/O)")
            .writable_within(1, 3),
        Tag::holding("COP", COP, U16)
            .describe("copy channel 1 to 2")
            .writable_within(0, 2),
        Tag::holding("CMD", CMD, U16)
            .describe("control word")
            .writable()
            .bits(cmd_bits()),
        Tag::holding("LFRD", LFRD, I16)
            .describe("speed reference")
            .unit("rpm")
            .writable(),
        Tag::holding("RFRD", RFRD, I16)
            .describe("output speed")
            .unit("rpm"),
        Tag::holding("ACC", ACC, U16)
            .describe("acceleration ramp time")
            .fix_point(1)
            .unit("s")
            .writable_within(1, 9999),
        Tag::holding("DEC", DEC, U16)
            .describe("deceleration ramp time")
            .fix_point(1)
            .unit("s")
            .writable_within(1, 9999),
        Tag::holding("THR", THR, U16)
            .describe("motor thermal state")
            .unit("%"),
    ]
}

/// The communication scanner's addresses (NMA, NCA) and values (NM, NC).
fn scanner_tags() -> Vec<Tag> {
    use DataType::U16;
    let mut tags = Vec::with_capacity(NMA.len() + NCA.len() + NM.len() + NC.len());
    for (i, address) in NMA.iter().enumerate() {
        tags.push(
            Tag::holding(format!("NMA{}", i + 1), *address, U16)
                .describe("scanner input address")
                .writable(),
        );
    }
    for (i, address) in NCA.iter().enumerate() {
        tags.push(
            Tag::holding(format!("NCA{}", i + 1), *address, U16)
                .describe("scanner output address")
                .writable(),
        );
    }
    for (i, address) in NM.iter().enumerate() {
        tags.push(
            Tag::holding(format!("NM{}", i + 1), *address, U16).describe("scanner input value"),
        );
    }
    for (i, address) in NC.iter().enumerate() {
        tags.push(
            Tag::holding(format!("NC{}", i + 1), *address, U16)
                .describe("scanner output value")
                .writable(),
        );
    }
    tags
}

/// 002 "Modbus-Funktionen": FC 03 63 words, FC 16 61 words, FC 23 20 / 20; no bit functions.
pub const LIMITS: RequestLimits = RequestLimits {
    read_bits: 0,
    read_registers: MAX_READ,
    write_bits: 0,
    write_registers: MAX_WRITE,
    read_write: Some(ReadWriteLimits {
        read: MAX_RW_READ,
        write: MAX_RW_WRITE,
    }),
    max_adu_len: MAX_ADU_LEN,
};

/// The words the drive sends for what it cannot deliver: 16#8000 for a parameter that does not
/// exist or is protected (002 "Lesen nicht vorhandener oder geschützter Parameter").
pub const SPECIAL_VALUES: SpecialValues = SpecialValues {
    words: &[(NOT_AVAILABLE, Quality::NotDefined)],
    ..SpecialValues::NONE
};

/// The communication scanner: NM1..NM8 read and NC1..NC8 written with one FC 23
/// (002 "Kommunikationsscanner").
pub const SCANNER: ScannerSpec = ScannerSpec {
    inputs_at: NM[0],
    outputs_at: NC[0],
    max_words: NM.len() as u16,
    source: "002 Kommunikationsscanner: NM1..NM8, NC1..NC8",
};

/// The profile's entry in [`super::registry::PROFILES`].
pub const REGISTERED: Registered = Registered {
    name: "altivar71",
    source: "002 Modbus-Funktionen",
    build: profile,
    limits: LIMITS,
    scanner: Some(SCANNER),
};

/// The Altivar 61/71 profile.
pub fn profile() -> DeviceProfile {
    DeviceProfile {
        name: "altivar71".to_owned(),
        default_address: DEFAULT_ADDRESS,
        tags: tags(),
        limits: LIMITS,
        functions: FUNCTIONS.to_vec(),
        special_values: SPECIAL_VALUES,
        keep_alive: Some(KeepAlive {
            tag: "CMD".to_owned(),
            timeout: COMMUNICATION_TIMEOUT,
            period: KEEP_ALIVE_PERIOD,
        }),
    }
}
