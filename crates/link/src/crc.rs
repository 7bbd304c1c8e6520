//! Checksums: CRC-16/CCITT-FALSE per ACK and FAIL segment and per SLIP frame,
//! CRC-32 (IEEE) per message.

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF): `crc16(b"123456789") == 0x29B1`.
pub fn crc16(data: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for &b in data {
        crc ^= (b as u16) << 8;
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

/// CRC-32 (IEEE 802.3), as zlib computes it.
pub fn crc32(data: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(data);
    h.finalize()
}

#[cfg(test)]
mod tests {
    #[test]
    fn check_values() {
        assert_eq!(super::crc16(b"123456789"), 0x29B1);
        assert_eq!(super::crc32(b"123456789"), 0xCBF4_3926);
    }
}
