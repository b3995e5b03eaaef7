//! Every event class and number of the CP 341 as static data.
//!
//! Source: manual 003 (RS422/485, English) 7.2 "Diagnostics via FB STATUS", checked entry by entry
//! against manual 000 (RS232, German) 7.2 "Diagnose über FB STATUS". Both list the same 80 events
//! in the same 10 classes; the RS232 manual adds no event of its own (its RS232-specific event,
//! 08 18h DSR/CTS = OFF, is in 003 too). Where the two texts differ, the entry says which one it
//! follows. Texts are the manual's, shortened where it repeats itself; the prefix "Modbus master
//! only:" and the like is the manual's "With ... only".

use super::{ids, EventId};

/// One event of the catalog: its id and the manual's description and remedy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EventInfo {
    /// Class and number.
    pub id: EventId,
    /// What happened (7.2 "Description").
    pub description: &'static str,
    /// What to do (7.2 "Remedy"); empty where the manual gives none (class 00h, 1E 0Dh).
    pub remedy: &'static str,
}

/// The event's catalog entry, `None` for an id the manual does not list.
pub fn lookup(id: EventId) -> Option<&'static EventInfo> {
    CATALOG
        .binary_search_by(|info| info.id.cmp(&id))
        .ok()
        .and_then(|i| CATALOG.get(i))
}

/// Every event of the catalog, sorted by class and number.
pub fn all() -> &'static [EventInfo] {
    &CATALOG
}

/// The manual's title of an event class in English, lower case, `None` for a class it does not use.
///
/// These strings are the `class_name` label of the event counters, so they never change at run
/// time and their number is bounded by this table.
pub fn class_name(class: u8) -> Option<&'static str> {
    CLASSES
        .iter()
        .find(|(c, _)| *c == class)
        .map(|(_, name)| *name)
}

/// Every event class of the catalog with its title, sorted by class.
pub fn classes() -> &'static [(u8, &'static str)] {
    CLASSES
}

/// The event of a Modbus master that received exception `code` 01..07 (7.2, 0E 61h..0E 67h).
pub fn master_exception_event(code: u8) -> Option<EventId> {
    match code {
        0x01..=0x07 => Some(EventId::new(0x0E, 0x60 + code)),
        _ => None,
    }
}

/// The "Event ID" the PG shows for a diagnostic buffer entry (003 7.3 "Diagnostic message"): "the
/// initial F1C8h is always the same. The rest of the ID code corresponds to event class and event
/// number"; here F1C8h in the high word and the STATUS word in the low word.
pub const fn diag_event_id(id: EventId) -> u32 {
    0xF1C8_0000 | id.status_word() as u32
}

/// Class titles (003 7.2 table headings, lower case).
const CLASSES: &[(u8, &str)] = &[
    (0x00, "cp start-up"),
    (0x01, "hardware fault on cp"),
    (0x02, "initialization error"),
    (0x03, "error parameterization of fbs"),
    (0x04, "cp detected error in data traffic cp - cpu"),
    (0x05, "error while processing cpu request"),
    (0x07, "send error"),
    (0x08, "receive error"),
    (
        0x0E,
        "loadable driver - general processing errors <processing of a bsend job>",
    ),
    (
        0x1E,
        "error during communication between cp and cpu via backplane bus",
    ),
];

const fn e(id: EventId, description: &'static str, remedy: &'static str) -> EventInfo {
    EventInfo {
        id,
        description,
        remedy,
    }
}

const REPLACE_CP: &str = "CP defective and must be replaced.";
const CHECK_PARTNER: &str = "Check for malfunction at the partner device, if necessary with an interface test device switched into the transmission line.";
const CHECK_PARTNER_ERRORS: &str = "Check whether the partner also shows an error, because not all data may have arrived (e.g. break on the line), because of serious disturbances, or because the partner device malfunctions; if necessary use an interface test device switched into the transmission line.";
const REPETITION_REMEDY: &str = "A repetition is not an error, but it can indicate disturbances on the transmission line or a partner behaving incorrectly. If the frame still has not been transferred after the maximum number of repetitions, an error number describing the first error that occurred is output.";
const CORRECT_SOURCE_DB: &str = "Correct your source DB.";
const CHECK_SLAVE: &str = "Check the slave device.";
const SEE_SLAVE_MANUAL: &str = "See the manual of the slave device.";
const SFCERR: &str = "Load the SFCERR variable from the instance DB.";

/// The catalog (003 7.2, 000 7.2), sorted by class and number. Entries per class: 00h 4, 01h 4,
/// 02h 1, 03h 1, 04h 5, 05h 5, 07h 9, 08h 16, 0Eh 31, 1Eh 4.
static CATALOG: [EventInfo; 80] = [
    // Class 00h "CP start-up".
    e(ids::PTP_PARAMS_ACCEPTED, "PtP parameters accepted.", ""),
    e(ids::PARAMS_ALREADY_ON_CP, "Parameters already on the CP (time stamps match).", ""),
    e(ids::CPU_TO_STOP, "Status transition of the CPU to STOP.", ""),
    e(ids::CPU_TO_RUN, "Status transition of the CPU to RUN/START-UP.", ""),
    // Class 01h "Hardware fault on CP".
    e(ids::OS_EPROM_TEST_FAILED, "Fault while testing the operating system EPROM of the CP.", REPLACE_CP),
    e(ids::RAM_TEST_FAILED, "RAM test of the CP faulty.", REPLACE_CP),
    e(ids::REQUEST_INTERFACE_DEFECTIVE, "Request interface of the CP defective.", REPLACE_CP),
    e(ids::FIRMWARE_FAULT, "Fault in the CP firmware.", "Switch the CP off and on again. If necessary, replace the CP."),
    // Class 02h "Initialization error".
    // 003 7.2 adds that RK512, which the CP 341 does not support, gives this error, and its
    // remedy says not to parameterize RK512. No line of the gateway can be set to RK512 (the
    // config reader refuses it), so the entry keeps the rule that holds on every line: the
    // interface could not be set up with the line's parameters (for a gateway: the port could not
    // be opened, or its driver refused the frame or RS485 mode), and the remedy is to correct them.
    e(
        ids::INVALID_PARAMETERIZATION,
        "Invalid parameterization detected at the start of parameterized communication; the interface could not be parameterized (the port could not be opened or its driver refused the line's settings, e.g. RS485 mode).",
        "Correct the line's parameters (port, frame, interface; the event's detail names the cause) and initiate a start-up; a port that is missing is opened again with back-off.",
    ),
    // Class 03h "Error parameterization of FBs" (not displayed in the diagnostic buffer).
    e(
        ids::INVALID_FB_PARAMETERS,
        "Invalid or no source/destination data type, invalid area (start address, length), DB invalid or missing (e.g. DB 0), or another data type invalid or missing.",
        "Check the parameterization on CPU and CP and correct it if necessary.",
    ),
    // Class 04h "CP detected error in data traffic CP - CPU".
    e(ids::ILLEGAL_DATA_TYPE, "Incorrect, unknown or illegal data type (e.g. wrong parameterization of the FB).", "Check the program for incorrect parameterization of the FB."),
    e(
        ids::CPU_TRANSFER_ERROR,
        "Error during data transmission between CPU and CP.",
        "If the fault persists, check that the function blocks called in the user program are parameterized correctly. Right after power on, no connection to the CPU is set up yet. If the fault is sporadic, the CPU is temporarily unable to accept data; with the ASCII driver and 3964(R) the receiving CP repeats the transfer until the data reach the CPU.",
    ),
    e(
        ids::CPU_RECEIVE_RETRY,
        "Error during data transmission between CPU and CP (reception): the CPU is temporarily overloaded, or its data area is temporarily unavailable (receive block called too infrequently or locked with EN = false); the request is queued for repetition.",
        "Reduce the number of communication calls, call the receive block more frequently, check whether the receive block is disabled for too long.",
    ),
    e(
        ids::CPU_RECEIVE_ABORTED,
        "Data cannot be received: the transfer to the CPU is cancelled after 10 s of attempts because the receive block is not called or disabled, access to the CPU data area is denied, or the CPU data area is too short.",
        "Check that the user program runs the receive block and does not disable it, that the destination data area exists and that it is long enough.",
    ),
    e(
        ids::CPU_TRANSFER_RESET,
        "Data transfer between CPU and CP cancelled by RESET: destination DB missing or too short, or RESET bit set at the FB.",
        "Create the destination DB in the user program or lengthen it.",
    ),
    // Class 05h "Error while processing CPU request".
    e(
        ids::REQUEST_ABORTED_BY_RESTART,
        "Current request aborted by a CP restart.",
        "No remedy at power on. Before re-parameterizing the CP from the programming device, make sure no request from the CPU is running.",
    ),
    e(ids::REQUEST_NOT_PERMITTED, "Request not permitted in this operating mode of the CP (e.g. device interface not parameterized).", "Parameterize the device interface."),
    e(
        ids::START_ADDRESS_OUT_OF_RANGE,
        "Start address too high for the data type, or start address or DB/DX number too low.",
        "Take the permissible start addresses and DB/DX numbers from the request tables.",
    ),
    e(ids::TRANSFER_LENGTH_INVALID, "Transmission length > 1 KiB too great for the CP, or too short for the interface parameter.", "Split the request into several shorter requests."),
    e(ids::MODBUS_SEND_LENGTH_INVALID, "Modbus master only: transmission length too large (> 4 KiB) or too small for SEND.", "Check the parameter LEN at SEND."),
    // Class 07h "Send error".
    e(
        ids::SEND_REPETITION,
        "Transmission of the first repetition: an error was detected while sending the frame, or the partner requested a repetition with NAK.",
        REPETITION_REMEDY,
    ),
    e(ids::SEND_SETUP_REJECTED, "3964(R) only: error during connection setup: after STX was sent, NAK or any other code (except DLE or STX) was received.", CHECK_PARTNER),
    e(
        ids::SEND_SETUP_TIMEOUT,
        "3964(R) only: acknowledgement delay time (QVZ) exceeded: after STX was sent, the partner did not answer within the acknowledgement delay time.",
        "The partner device is too slow or not ready to receive, or the send line is broken. Check for malfunction at the partner device, if necessary with an interface test device.",
    ),
    e(ids::SEND_ABORTED_BY_PARTNER, "3964(R) only: termination by the partner: one or more characters were received from the partner during the send.", CHECK_PARTNER_ERRORS),
    e(
        ids::SEND_END_REJECTED,
        "3964(R) only: error at the end of the connection: the partner rejected the frame with NAK or another code (except DLE), or the acknowledgement (DLE) came too early.",
        CHECK_PARTNER_ERRORS,
    ),
    e(
        ids::SEND_END_TIMEOUT,
        "3964(R) only: acknowledgement delay time exceeded at the end of the connection, or response monitoring time exceeded after the send frame: no answer to DLE ETX within the acknowledgement delay time.",
        "The partner device is faulty or too slow; if necessary check with an interface test device.",
    ),
    e(
        ids::SEND_FLOW_CONTROL_TIMEOUT,
        "ASCII driver only: the waiting time for XON or for CTS = ON has elapsed.",
        "The partner has a fault, is too slow or is off-line. Check the partner or change the parameterization.",
    ),
    e(
        ids::SEND_SETUP_ATTEMPTS_EXHAUSTED,
        "Connection setup not possible: the number of permitted setup attempts was exceeded.",
        "Check the interface cable and the transmission parameters, and that the receive function between CPU and CP is parameterized correctly at the partner.",
    ),
    e(ids::SEND_ATTEMPTS_EXHAUSTED, "The data could not be transmitted: the permitted number of transmission attempts was exceeded.", "Check the interface cable and the transmission parameters."),
    // Class 08h "Receive error".
    e(
        ids::RECEIVE_REPETITION,
        "Expectation of the first repetition: an error was detected on receipt of a frame, and the CP requested a repetition from the partner with NAK.",
        REPETITION_REMEDY,
    ),
    e(
        ids::RECEIVE_SETUP_ERROR,
        "3964(R) only: error during connection setup: in idle mode one or more codes other than NAK or STX were received; or after STX the partner sent more codes without waiting for DLE; or an undefined code was received while the partner was powering on.",
        CHECK_PARTNER,
    ),
    e(
        ids::RECEIVE_LOGICAL_ERROR,
        "3964(R) only: logical error during receiving: after DLE a further code other than DLE or ETX was received.",
        "Check that the partner always doubles DLE in the header and the data and releases the connection with DLE ETX. Check for malfunction at the partner device.",
    ),
    e(
        ids::CHARACTER_DELAY_EXCEEDED,
        "Character delay time (ZVZ) exceeded: two successive characters were not received within the character delay time, or (3964(R) only) the first character after DLE during connection setup was not received within it.",
        "The partner device is faulty or too slow; check with an interface test device.",
    ),
    e(
        ids::BCC_ERROR,
        "3964(R) only: error in the block check character (BCC): the value calculated internally does not match the BCC received from the partner at the end of the connection.",
        "Check whether the connection is badly disturbed (other error codes then appear occasionally too). Check for malfunction at the partner device.",
    ),
    e(ids::NO_FREE_RECEIVE_BUFFER, "There is no free receive buffer available.", "Call FB P_RCV_RK more frequently."),
    e(
        ids::CHARACTER_ERROR,
        "Transmission error (parity, stop bit or overflow error) detected. 3964(R): a faulty character in idle mode is reported at once; during send or receive repetitions are initiated.",
        "Disturbances cause repetitions and lower the user data throughput, and raise the danger of an undetected error. Correct the system setup or line installation; check the cable and that both devices use the same baud rate, parity and number of stop bits.",
    ),
    // 003 adds the two-wire hint; 000 (RS232) has only the first sentence of the remedy.
    e(
        ids::LINE_BREAK,
        "BREAK: the receive line to the partner is interrupted.",
        // 003 7.2 names the RS422/485 receive pair R(A), R(B); the remedy here holds for every
        // interface, including RS232 and a port that went away (a USB adapter unplugged).
        "Reconnect or switch the partner on again; reconnect the port (cable, USB adapter), which is opened again with back-off. Check the pin assignment of the receive line (RS422/485: the 2-wire receive line R(A), R(B); RS232: RxD).",
    ),
    e(ids::ATTEMPTS_MISMATCH, "The settings for transmission attempts differ between the CP and the partner.", "Parameterize the same number of transmission attempts at the partner as at the CP. Check for malfunction at the partner device."),
    e(
        ids::FRAME_TOO_LONG,
        "A received frame was longer than agreed, or the parameterized receive buffer is too short.",
        "Correct the partner, or enlarge the receive buffer.",
    ),
    // 000 5.4 names the diagnostic buffer text "DSR = OFF automat. Bedienung d. V24-Signale".
    e(
        ids::DSR_OR_CTS_OFF,
        "(Modbus) ASCII driver only: DSR = OFF or CTS = OFF (automatic operation of the V24 signals).",
        "The partner switched DSR or CTS to OFF before or during a transmission. Check the partner's control of the RS232 secondary signals.",
    ),
    e(
        ids::MODBUS_NO_REPLY,
        "Modbus master only: a request was sent and the reply monitoring time elapsed without the start of a reply.",
        "Check whether the line is interrupted, that baud rate, data bits, parity and stop bits are the same at the CP and the partner, that the reply monitoring time is long enough, and that the slave address exists.",
    ),
    e(
        ids::MODBUS_WRONG_SLAVE_CHAR,
        "Modbus master RTU only: the first character of the reply differs from the slave address sent in the request (operating mode \"normal\").",
        "The wrong slave replied. Check whether the transmission line is interrupted.",
    ),
    e(ids::MODBUS_RECEIVE_OVERFLOW, "Modbus master only: overflow of the receive buffer of the CP while receiving the reply.", "Check the protocol settings of the slave."),
    e(ids::MODBUS_ASCII_WRONG_START, "Modbus master ASCII only: a wrong start character was received (not ':' 3Ah).", "Check the protocol settings of the slave."),
    e(
        ids::MODBUS_ASCII_START_IN_FRAME,
        "Modbus master ASCII only: a start character was received inside a frame; the first part is discarded and reception restarts with the second start character.",
        "Check whether the transmission line is interrupted. This does not fail the send job; it only appears in the diagnostic buffer.",
    ),
    // Class 0Eh "Loadable driver - general processing errors <processing of a BSEND job>".
    e(ids::SLAVE_CPU_TIMEOUT, "Modbus slave only: time-out during the data transfer to the CPU.", "Check the CP-CPU interface."),
    e(
        ids::SLAVE_BIT_AREA_ERROR,
        "Modbus slave only: error accessing one of the CPU areas memory bits, outputs, timers, counters or inputs with FC 01 or FC 02, e.g. the input does not exist or the read goes beyond the end of the area.",
        "Check that the addressed CPU area exists and that the access does not go beyond its end.",
    ),
    // 003 says "FC 02, 04, 06, 16"; 000 says "FC 03, 04, 06, 16", which matches 6.4.8 (FC 02 reads bits).
    e(
        ids::SLAVE_DB_ERROR,
        "Modbus slave only: error accessing the CPU area data block with FC 03, 04, 06 or 16: the data block does not exist or is too short.",
        "Check that the addressed data block exists and is long enough.",
    ),
    e(ids::MASTER_LEN_TOO_SMALL, "Modbus master only: value of parameter LEN at SFB SEND too small.", "The minimum length is 2 bytes."),
    e(
        ids::MASTER_LEN_TOO_SMALL_FOR_FUNCTION,
        "Modbus master only: value of parameter LEN at SFB SEND too small for the function code passed.",
        "The minimum length for this function code is 6 bytes.",
    ),
    e(ids::MASTER_ILLEGAL_FUNCTION, "Modbus master only: the function code passed is illegal.", "Use only the function codes of 6.4.4 \"Modbus Master - Function codes\"."),
    e(ids::MASTER_BROADCAST_NOT_PERMITTED, "Modbus master only: slave address 0 (broadcast) is not permitted with this function code.", "Use slave address 0 only with the suitable function codes."),
    e(
        ids::MASTER_BIT_COUNT_OUT_OF_RANGE,
        "Modbus master only: the amount of bits passed is not within 1..2040 (Modbus master ASCII: 1..2008).",
        CORRECT_SOURCE_DB,
    ),
    e(
        ids::MASTER_REGISTER_COUNT_OUT_OF_RANGE,
        "Modbus master only: the amount of registers passed is not within 1..127 (Modbus master ASCII: 1..125, with 32 bit 1..62).",
        CORRECT_SOURCE_DB,
    ),
    e(
        ids::MASTER_WRITE_COUNT_OUT_OF_RANGE,
        "Modbus master only: FC 15 or 16: the amount of bits or registers passed is not within 1..2040 or 1..127 (Modbus master ASCII: 1..1976 or 1..123, with 32 bit 1..61).",
        CORRECT_SOURCE_DB,
    ),
    e(
        ids::MASTER_WRITE_LEN_TOO_SMALL,
        "Modbus master only: FC 15 or 16: the parameter LEN at SFB SEND is too small for the amount of bits or registers passed.",
        "Increase LEN at SEND until enough user data are transferred to the CP for the amount of bits or registers.",
    ),
    e(
        ids::MASTER_COIL_VALUE_INVALID,
        "Modbus master only: FC 05: the code in the SEND source DB for \"set bit\" (FF00h) or \"delete bit\" (0000h) is wrong.",
        "Only FF00h and 0000h are permitted.",
    ),
    e(ids::MASTER_DIAGNOSTIC_CODE_INVALID, "Modbus master only: FC 08: the diagnostic code in the SEND source DB is wrong.", "Only the diagnostic code 0000h is permitted."),
    e(
        ids::MASTER_32BIT_FUNCTION_INVALID,
        "Modbus master ASCII only: access to 32-bit registers (bit 6 of the function code set) is only allowed with FC 03, 06 and 16.",
        CORRECT_SOURCE_DB,
    ),
    e(ids::MASTER_ILLEGAL_R_TYP, "Modbus master only: the R_TYP specified at SFB SEND is illegal with this driver.", "Enter \"X\" as R_TYP."),
    e(
        ids::MODBUS_WRONG_SLAVE,
        "Modbus master only: slave address incorrect: the received slave address differs from the address sent.",
        "The wrong slave replied. Check whether the transmission line is interrupted.",
    ),
    e(ids::MODBUS_WRONG_FUNCTION, "Modbus master only: function code incorrect: the function code of the reply differs from the function code sent.", CHECK_SLAVE),
    e(
        ids::MODBUS_BYTE_UNDERFLOW,
        "Modbus master only: byte underflow: fewer characters received than the byte count of the reply or the function code demands.",
        CHECK_SLAVE,
    ),
    e(
        ids::MODBUS_BYTE_OVERFLOW,
        "Modbus master only: byte overflow: more characters received than the byte count of the reply or the function code demands.",
        CHECK_SLAVE,
    ),
    e(ids::MODBUS_BYTE_COUNT_TOO_SMALL, "Modbus master only: byte count too small: the byte count received in the reply is too small.", CHECK_SLAVE),
    e(ids::MODBUS_BYTE_COUNT_WRONG, "Modbus master only: byte count wrong: the byte count received in the reply is wrong.", CHECK_SLAVE),
    e(
        ids::MODBUS_ECHO_WRONG,
        "Modbus master only: echo wrong: the request data echoed by the slave (amount of bits, ...) differ from the data sent.",
        CHECK_SLAVE,
    ),
    e(
        ids::MODBUS_CHECKSUM_ERROR,
        "Modbus master only: CRC check incorrect (Modbus master ASCII: LRC check incorrect) in the reply from the slave.",
        CHECK_SLAVE,
    ),
    e(
        ids::MODBUS_ASCII_INVALID_CHARACTER,
        "Modbus master ASCII only: a character of the reply is not an ASCII hex character (0..9, A..F).",
        "Check the slave device; make sure it is in ASCII mode, not RTU.",
    ),
    e(ids::MODBUS_EXCEPTION_ILLEGAL_FUNCTION, "Modbus master only: reply with exception code 01: illegal function.", SEE_SLAVE_MANUAL),
    e(ids::MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS, "Modbus master only: reply with exception code 02: illegal data address.", SEE_SLAVE_MANUAL),
    e(ids::MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE, "Modbus master only: reply with exception code 03: illegal data value.", SEE_SLAVE_MANUAL),
    e(ids::MODBUS_EXCEPTION_DEVICE_FAILURE, "Modbus master only: reply with exception code 04: failure in associated device.", SEE_SLAVE_MANUAL),
    e(ids::MODBUS_EXCEPTION_ACKNOWLEDGE, "Modbus master only: reply with exception code 05: acknowledge.", SEE_SLAVE_MANUAL),
    e(ids::MODBUS_EXCEPTION_BUSY, "Modbus master only: reply with exception code 06: busy, rejected message.", SEE_SLAVE_MANUAL),
    e(ids::MODBUS_EXCEPTION_NEGATIVE_ACK, "Modbus master only: reply with exception code 07: negative acknowledgement.", SEE_SLAVE_MANUAL),
    // Class 1Eh "Error during communication between CP and CPU via backplane bus".
    e(ids::BACKPLANE_REQUEST_ABORTED, "Request aborted by a complete restart, warm restart or reset.", ""),
    e(
        ids::BACKPLANE_READ_RECORD_ERROR,
        "Static error of SFC 59 RD_REC (read data record); its RET_VAL is in the variable SFCERR of the instance DB.",
        SFCERR,
    ),
    e(
        ids::BACKPLANE_WRITE_RECORD_ERROR,
        "Static error of SFC 58 WR_REC (write data record); its RET_VAL is in the variable SFCERR of the instance DB.",
        SFCERR,
    ),
    e(ids::BACKPLANE_LEN_ILLEGAL, "Number of bytes in the LEN parameter of the FBs illegal.", "Keep to the range 1..1024 bytes."),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn remedies_fit_every_line_of_the_gateway() {
        // No remedy asks for something a gateway line cannot be set to (RK512), and the events
        // of a port that cannot be set up or went away say what to do with the port.
        for info in all() {
            assert!(!info.remedy.contains("RK512"), "{:?}", info.id);
            assert!(!info.description.contains("RK512"), "{:?}", info.id);
        }
        for id in [ids::INVALID_PARAMETERIZATION, ids::LINE_BREAK] {
            let remedy = lookup(id).map(|i| i.remedy).unwrap_or_default();
            assert!(remedy.contains("port"), "{id:?}: {remedy}");
        }
    }

    #[test]
    fn sorted_for_binary_search() {
        assert!(CATALOG.windows(2).all(|w| w[0].id < w[1].id));
        assert!(CLASSES.windows(2).all(|w| w[0].0 < w[1].0));
    }

    #[test]
    fn exception_events() {
        assert_eq!(
            master_exception_event(2),
            Some(ids::MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS)
        );
        assert_eq!(
            master_exception_event(7),
            Some(ids::MODBUS_EXCEPTION_NEGATIVE_ACK)
        );
        assert_eq!(master_exception_event(0), None);
        assert_eq!(master_exception_event(0x0B), None);
        assert_eq!(diag_event_id(ids::MODBUS_NO_REPLY), 0xF1C8_0830);
    }
}
