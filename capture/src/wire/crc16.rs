//! The CRC-16 both serial codecs use: polynomial 0x1021, MSB first, no reflection, no final
//! xor. The protocols differ only in the initial value ([`super::fslp::crc16`]: 0x1D0F,
//! CRC-16/AUG-CCITT; [`super::rig_protocol::crc16_ccitt_false`]: 0xFFFF, CRC-16/CCITT-FALSE).

/// CRC-16 with polynomial 0x1021 (MSB first, no final xor) of `data`, starting from `init`.
pub(crate) fn crc16_1021(init: u16, data: &[u8]) -> u16 {
    let mut crc = init;
    for &byte in data {
        crc ^= u16::from(byte) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}
