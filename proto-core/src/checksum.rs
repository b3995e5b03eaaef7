//! Checksums: CRC-16/Modbus (RTU), LRC (Modbus ASCII), BCC (3964R).
//!
//! All three are pure functions over the bytes as they are covered on the wire; callers decide which
//! bytes that is (the RTU address and PDU, the ASCII address and PDU before hex encoding, the 3964R
//! bytes after STX up to and including DLE ETX as transmitted).

/// The reflected CRC-16/Modbus polynomial (Modbus over Serial Line V1.02, 6.2.2: 0xA001).
const CRC16_MODBUS_POLY: u16 = 0xA001;

/// The CRC register's start value (Modbus over Serial Line V1.02, 6.2.2: all ones).
const CRC16_MODBUS_INIT: u16 = 0xFFFF;

/// One table entry a byte value, computed at compile time from [`CRC16_MODBUS_POLY`].
const CRC16_MODBUS_TABLE: [u16; 256] = crc16_table();

const fn crc16_table() -> [u16; 256] {
    let mut table = [0u16; 256];
    let mut byte = 0;
    while byte < 256 {
        #[allow(clippy::cast_possible_truncation)] // byte < 256
        let mut crc = byte as u16;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ CRC16_MODBUS_POLY
            } else {
                crc >> 1
            };
            bit += 1;
        }
        table[byte] = crc;
        byte += 1;
    }
    table
}

/// CRC-16/Modbus of `data` (poly 0xA001 reflected, init 0xFFFF, no final XOR).
///
/// On the wire the low byte goes first (003 6.4.3 "CRC check"; Modbus over Serial Line V1.02,
/// 2.5.1.2): use [`u16::to_le_bytes`].
pub fn crc16_modbus(data: &[u8]) -> u16 {
    data.iter().fold(CRC16_MODBUS_INIT, |crc, &byte| {
        let index = usize::from((crc ^ u16::from(byte)) & 0x00FF);
        // `index` < 256 by the mask, so `get` always finds an entry.
        (crc >> 8) ^ CRC16_MODBUS_TABLE.get(index).copied().unwrap_or(0)
    })
}

/// Modbus ASCII LRC of `data` (the binary address and PDU, before hex encoding): the two's
/// complement of the 8-bit sum without carry (003 6.4.2.2; Modbus over Serial Line V1.02, 6.2.1).
pub fn lrc(data: &[u8]) -> u8 {
    data.iter()
        .fold(0u8, |sum, &byte| sum.wrapping_add(byte))
        .wrapping_neg()
}

/// 3964R block check character: the XOR of every byte (003 6.3, "Block checksum"), so a doubled
/// DLE contributes twice and cancels.
pub fn bcc(data: &[u8]) -> u8 {
    data.iter().fold(0u8, |acc, &byte| acc ^ byte)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc16_check_value() {
        // The CRC catalogue's check value of CRC-16/MODBUS for "123456789".
        assert_eq!(crc16_modbus(b"123456789"), 0x4B37);
    }

    #[test]
    fn crc16_of_empty_input_is_init() {
        assert_eq!(crc16_modbus(&[]), 0xFFFF);
    }

    #[test]
    fn crc16_matches_altivar_fc03_request() {
        // 002, FC03 example: 02 03 0C 1E 00 04 then CRC 27 6C (low byte first).
        let crc = crc16_modbus(&[0x02, 0x03, 0x0C, 0x1E, 0x00, 0x04]);
        assert_eq!(crc.to_le_bytes(), [0x27, 0x6C]);
    }

    #[test]
    fn crc16_matches_bitwise_definition() {
        fn bitwise(data: &[u8]) -> u16 {
            let mut crc = 0xFFFFu16;
            for &b in data {
                crc ^= u16::from(b);
                for _ in 0..8 {
                    crc = if crc & 1 == 1 {
                        (crc >> 1) ^ 0xA001
                    } else {
                        crc >> 1
                    };
                }
            }
            crc
        }
        let data: Vec<u8> = (0..=255u8).collect();
        for len in [0, 1, 2, 7, 64, 256] {
            assert_eq!(
                crc16_modbus(&data[..len]),
                bitwise(&data[..len]),
                "len {len}"
            );
        }
    }

    #[test]
    fn lrc_of_fc03_request() {
        // Modbus over Serial Line V1.02, 6.2.1 style example: 11 03 00 6B 00 03 -> LRC 7E.
        assert_eq!(lrc(&[0x11, 0x03, 0x00, 0x6B, 0x00, 0x03]), 0x7E);
        assert_eq!(lrc(&[]), 0);
        // The sum of the data and its LRC is zero modulo 256.
        let data = [0xFF, 0xFF, 0x01];
        assert_eq!(data.iter().fold(lrc(&data), |s, &b| s.wrapping_add(b)), 0);
    }

    #[test]
    fn bcc_of_3964r_examples() {
        // vectors: "ABC" -> 41 42 43 10 03 with BCC 53; 10 20 -> 10 10 20 10 03 with BCC 33.
        assert_eq!(bcc(&[0x41, 0x42, 0x43, 0x10, 0x03]), 0x53);
        assert_eq!(bcc(&[0x10, 0x10, 0x20, 0x10, 0x03]), 0x33);
        assert_eq!(bcc(&[]), 0);
    }
}
