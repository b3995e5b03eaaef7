//! A small pcapng writer for the frame monitor's captures (IETF draft "PCAP Next Generation
//! (pcapng) Capture File Format": Section Header, Interface Description and Enhanced Packet
//! blocks, little-endian).
//!
//! One capture holds one line: interface 0 is what the line received, interface 1 what it sent,
//! each with the link type of the line's protocol (Wireshark's "User DLTs", 147..162):
//!
//! ```text
//!   DLT 147 (USER0)  Modbus RTU: Wireshark's own "mbrtu" dissector through the user_dlts table
//!   DLT 148 (USER1)  3964(R): deploy/wireshark/cp341_3964r.lua
//!   DLT 149 (USER2)  anything else (Modbus ASCII, ASCII telegrams, raw): bytes
//! ```
//!
//! Each packet carries the frame's first-byte time (microseconds), its direction (`epb_flags`
//! inbound/outbound) and a comment with the verdict, the summary and the last byte's time.

use std::time::{SystemTime, UNIX_EPOCH};

use proto_core::monitor::{Direction, FrameKind};

use super::monitor::{Frame, FrameMonitor};

/// The link type of Modbus RTU frames: `LINKTYPE_USER0`.
pub const DLT_MODBUS_RTU: u16 = 147;
/// The link type of 3964(R) frames: `LINKTYPE_USER1`.
pub const DLT_3964R: u16 = 148;
/// The link type of other frames: `LINKTYPE_USER2`.
pub const DLT_OTHER: u16 = 149;
/// The media type of a pcapng file.
pub const MEDIA_TYPE: &str = "application/x-pcapng";

const SHB: u32 = 0x0A0D_0D0A;
const IDB: u32 = 0x0000_0001;
const EPB: u32 = 0x0000_0006;
const BYTE_ORDER_MAGIC: u32 = 0x1A2B_3C4D;
const OPT_END: u16 = 0;
const OPT_COMMENT: u16 = 1;
const SHB_USERAPPL: u16 = 4;
const IF_NAME: u16 = 2;
const IF_DESCRIPTION: u16 = 3;
const IF_TSRESOL: u16 = 9;
const EPB_FLAGS: u16 = 2;
/// `epb_flags` bits 0-1: 01 inbound, 10 outbound.
const INBOUND: u32 = 1;
const OUTBOUND: u32 = 2;
/// No frame is longer (the monitor cuts at 4096 bytes).
const SNAPLEN: u32 = 65_535;

/// The link type of a line's frames.
pub fn link_type(kind: FrameKind) -> u16 {
    match kind {
        FrameKind::ModbusRtu(_) => DLT_MODBUS_RTU,
        FrameKind::Proc3964 { .. } => DLT_3964R,
        FrameKind::Raw | FrameKind::ModbusAscii(_) | FrameKind::Telegram(_) => DLT_OTHER,
    }
}

/// `frames` of `monitor`'s line as a pcapng file.
pub fn capture(monitor: &FrameMonitor, frames: &[Frame]) -> Vec<u8> {
    let mut out = header(monitor);
    out.reserve(frames.iter().map(|f| f.bytes.len() + 160).sum::<usize>());
    for frame in frames {
        packet(&mut out, monitor, frame);
    }
    out
}

/// The start of a pcapng file of `monitor`'s line: the section header and the two interfaces.
/// A file is this followed by [`packet`]s (a capture written as it is recorded).
pub fn header(monitor: &FrameMonitor) -> Vec<u8> {
    let mut out = Vec::with_capacity(256);
    let mut opts = Vec::new();
    option(
        &mut opts,
        SHB_USERAPPL,
        concat!("cp341-gateway ", env!("CARGO_PKG_VERSION")).as_bytes(),
    );
    end_options(&mut opts);
    let mut body = Vec::with_capacity(16 + opts.len());
    body.extend_from_slice(&BYTE_ORDER_MAGIC.to_le_bytes());
    body.extend_from_slice(&1u16.to_le_bytes()); // major version
    body.extend_from_slice(&0u16.to_le_bytes()); // minor version
    body.extend_from_slice(&(-1i64).to_le_bytes()); // section length: not given
    body.extend_from_slice(&opts);
    block(&mut out, SHB, &body);

    let link = link_type(monitor.kind());
    for direction in monitor.directions() {
        let mut opts = Vec::new();
        let name = format!("{} {}", monitor.line(), direction.as_str());
        option(&mut opts, IF_NAME, name.as_bytes());
        let what = match direction {
            Direction::Rx => "received by the gateway",
            Direction::Tx => "sent by the gateway",
            Direction::A => "partner A transmitted (first port)",
            Direction::B => "partner B transmitted (second port)",
        };
        option(
            &mut opts,
            IF_DESCRIPTION,
            format!("line {}: frames {what}", monitor.line()).as_bytes(),
        );
        option(&mut opts, IF_TSRESOL, &[6]); // microseconds
        end_options(&mut opts);
        let mut body = Vec::with_capacity(8 + opts.len());
        body.extend_from_slice(&link.to_le_bytes());
        body.extend_from_slice(&0u16.to_le_bytes()); // reserved
        body.extend_from_slice(&SNAPLEN.to_le_bytes());
        body.extend_from_slice(&opts);
        block(&mut out, IDB, &body);
    }
    out
}

/// Appends `frame` to a file begun with [`header`] as an Enhanced Packet Block.
pub fn packet(out: &mut Vec<u8>, monitor: &FrameMonitor, frame: &Frame) {
    // One interface per direction, in the monitor's order; a listener's two sides are both
    // inbound to it.
    let interface = u32::from(frame.direction == monitor.directions()[1]);
    let flags = match frame.direction {
        Direction::Tx => OUTBOUND,
        Direction::Rx | Direction::A | Direction::B => INBOUND,
    };
    let ts = micros(frame.first);
    let len = u32::try_from(frame.bytes.len()).unwrap_or(u32::MAX);
    let d = monitor.describe(frame);
    let comment = format!(
        "#{} {}: {}; last byte +{} us",
        frame.seq,
        d.verdict.as_str(),
        d.summary,
        frame.last_mono.saturating_sub(frame.first_mono).as_micros()
    );
    let mut body = Vec::with_capacity(28 + frame.bytes.len() + comment.len() + 16);
    body.extend_from_slice(&interface.to_le_bytes());
    body.extend_from_slice(&((ts >> 32) as u32).to_le_bytes());
    body.extend_from_slice(&((ts & 0xFFFF_FFFF) as u32).to_le_bytes());
    body.extend_from_slice(&len.to_le_bytes()); // captured
    body.extend_from_slice(&len.to_le_bytes()); // original
    body.extend_from_slice(&frame.bytes);
    pad(&mut body);
    option(&mut body, OPT_COMMENT, comment.as_bytes());
    option(&mut body, EPB_FLAGS, &flags.to_le_bytes());
    end_options(&mut body);
    block(out, EPB, &body);
}

fn micros(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX))
}

/// A block: type, total length, body (a multiple of 4 bytes), total length again.
fn block(out: &mut Vec<u8>, kind: u32, body: &[u8]) {
    let total = u32::try_from(body.len() + 12).unwrap_or(u32::MAX);
    out.extend_from_slice(&kind.to_le_bytes());
    out.extend_from_slice(&total.to_le_bytes());
    out.extend_from_slice(body);
    out.extend_from_slice(&total.to_le_bytes());
}

/// An option: code, length, value padded to 32 bits (values longer than 65535 bytes are cut).
fn option(out: &mut Vec<u8>, code: u16, value: &[u8]) {
    let value = value.get(..usize::from(u16::MAX)).unwrap_or(value);
    out.extend_from_slice(&code.to_le_bytes());
    out.extend_from_slice(&u16::try_from(value.len()).unwrap_or(u16::MAX).to_le_bytes());
    out.extend_from_slice(value);
    pad(out);
}

fn end_options(out: &mut Vec<u8>) {
    out.extend_from_slice(&OPT_END.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
}

fn pad(out: &mut Vec<u8>) {
    while out.len() % 4 != 0 {
        out.push(0);
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use proto_core::monitor::Role;

    use super::*;

    fn u32_at(b: &[u8], at: usize) -> u32 {
        u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
    }

    #[test]
    fn blocks_are_framed_padded_and_timestamped_in_microseconds() {
        let monitor = FrameMonitor::new("drive", FrameKind::ModbusRtu(Role::Master), 4, None);
        let first = UNIX_EPOCH + Duration::from_micros(1_700_000_000_123_456);
        let frame = Frame {
            seq: 7,
            direction: Direction::Tx,
            first,
            last: first + Duration::from_micros(4000),
            first_mono: Duration::from_micros(10),
            last_mono: Duration::from_micros(4010),
            bytes: vec![0x01, 0x03, 0x00, 0x00, 0x00, 0x01, 0x84, 0x0A],
            errors: Vec::new(),
        };
        let file = capture(&monitor, &[frame]);
        // Walk the blocks: SHB, two IDBs, one EPB; each total length at both ends.
        let mut at = 0;
        let mut kinds = Vec::new();
        while at < file.len() {
            let kind = u32_at(&file, at);
            let total = u32_at(&file, at + 4) as usize;
            assert_eq!(total % 4, 0);
            assert_eq!(u32_at(&file, at + total - 4) as usize, total);
            kinds.push(kind);
            if kind == IDB {
                assert_eq!(
                    u16::from_le_bytes([file[at + 8], file[at + 9]]),
                    DLT_MODBUS_RTU
                );
            }
            if kind == EPB {
                assert_eq!(u32_at(&file, at + 8), 1, "sent: interface 1");
                let ts =
                    u64::from(u32_at(&file, at + 12)) << 32 | u64::from(u32_at(&file, at + 16));
                assert_eq!(ts, 1_700_000_000_123_456);
                assert_eq!(u32_at(&file, at + 20), 8);
                assert_eq!(
                    &file[at + 28..at + 36],
                    &[0x01, 0x03, 0x00, 0x00, 0x00, 0x01, 0x84, 0x0A]
                );
                let rest = String::from_utf8_lossy(&file[at + 36..at + total]);
                assert!(
                    rest.contains("#7 ok: slave 1 read holding registers start 0 quantity 1, CRC ok; last byte +4000 us"),
                    "{rest}"
                );
            }
            at += total;
        }
        assert_eq!(kinds, [SHB, IDB, IDB, EPB]);
        assert_eq!(u32_at(&file, 8), BYTE_ORDER_MAGIC);
    }

    /// A two-port tap line's capture: interface 0 is side a, interface 1 side b, named so, and
    /// both inbound.
    #[test]
    fn a_two_port_lines_sides_are_its_two_interfaces_both_inbound() {
        let monitor = FrameMonitor::new("y", FrameKind::Proc3964 { bcc: true }, 4, None)
            .with_directions([Direction::A, Direction::B]);
        let frame = |seq, direction, byte| Frame {
            seq,
            direction,
            first: UNIX_EPOCH + Duration::from_secs(1_700_000_000),
            last: UNIX_EPOCH + Duration::from_secs(1_700_000_000),
            first_mono: Duration::ZERO,
            last_mono: Duration::ZERO,
            bytes: vec![byte],
            errors: Vec::new(),
        };
        let file = capture(
            &monitor,
            &[frame(1, Direction::A, 0x02), frame(2, Direction::B, 0x10)],
        );
        let (mut at, mut names, mut packets) = (0, Vec::new(), Vec::new());
        while at < file.len() {
            let kind = u32_at(&file, at);
            let total = u32_at(&file, at + 4) as usize;
            let block = &file[at..at + total];
            if kind == IDB {
                let text = String::from_utf8_lossy(block);
                names.push(
                    ["y a", "y b"]
                        .into_iter()
                        .find(|n| text.contains(n))
                        .unwrap_or("?"),
                );
            }
            if kind == EPB {
                // The flags option (code 2, length 4) follows the comment: its value's low bits.
                let flags = block
                    .windows(4)
                    .rposition(|w| w == [0x02, 0x00, 0x04, 0x00])
                    .map(|i| u32_at(block, i + 4));
                packets.push((u32_at(block, 8), block[28], flags));
            }
            at += total;
        }
        assert_eq!(names, ["y a", "y b"]);
        assert_eq!(
            packets,
            [(0, 0x02, Some(INBOUND)), (1, 0x10, Some(INBOUND))]
        );
    }

    #[test]
    fn link_types_by_protocol() {
        assert_eq!(link_type(FrameKind::ModbusRtu(Role::Slave)), 147);
        assert_eq!(link_type(FrameKind::Proc3964 { bcc: true }), 148);
        assert_eq!(link_type(FrameKind::Raw), 149);
    }
}
