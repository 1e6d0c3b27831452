//! CRC-32 (IEEE 802.3, the one of zlib and PNG), table-driven, no allocation.

const TABLE: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
};

/// Incremental CRC-32: feed bytes in any chunking, same result.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Crc32(u32);

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32 {
    /// A fresh checksum.
    pub const fn new() -> Self {
        Crc32(0xFFFF_FFFF)
    }

    /// Feeds bytes.
    pub fn update(&mut self, bytes: &[u8]) {
        let mut c = self.0;
        for &b in bytes {
            c = TABLE[((c ^ u32::from(b)) & 0xFF) as usize] ^ (c >> 8);
        }
        self.0 = c;
    }

    /// The checksum of everything fed so far.
    pub fn finish(&self) -> u32 {
        self.0 ^ 0xFFFF_FFFF
    }
}

/// CRC-32 of a byte slice.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut c = Crc32::new();
    c.update(bytes);
    c.finish()
}

/// Where a single flipped bit lies in `payload ++ field` (the CRC-32 of
/// `payload`, little-endian, as a frame carries it), given the syndrome
/// `crc32(payload) ^ field` of what arrived: `(byte index, bit mask)`.
/// A CRC is linear, so a flip of bit `b` in byte `j` changes the checksum
/// by a value that depends only on `b` and the bytes after `j`: computed
/// from the end backwards, eight values per byte. CRC-32 has a Hamming
/// distance of at least 4 over any frame this project sends, so a single
/// flip is always found, and found at one place only.
pub fn locate_bit_flip(payload_len: usize, syndrome: u32) -> Option<(usize, u8)> {
    if syndrome == 0 {
        return None;
    }
    if syndrome.count_ones() == 1 {
        let k = syndrome.trailing_zeros() as usize;
        return Some((payload_len + k / 8, 1 << (k % 8)));
    }
    let mut delta: [u32; 8] = core::array::from_fn(|b| TABLE[1 << b]);
    for j in (0..payload_len).rev() {
        if let Some(b) = delta.iter().position(|&d| d == syndrome) {
            return Some((j, 1 << b));
        }
        for d in delta.iter_mut() {
            *d = TABLE[(*d & 0xFF) as usize] ^ (*d >> 8);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_single_flip_is_located() {
        let payload: [u8; 40] = core::array::from_fn(|i| (i * 37 + 11) as u8);
        let field = super::crc32(&payload).to_le_bytes();
        let mut frame = [0u8; 44];
        frame[..40].copy_from_slice(&payload);
        frame[40..].copy_from_slice(&field);
        for j in 0..44 {
            for b in 0..8 {
                let mut bad = frame;
                bad[j] ^= 1 << b;
                let (p, f) = bad.split_at(40);
                let s = super::crc32(p) ^ u32::from_le_bytes([f[0], f[1], f[2], f[3]]);
                assert_eq!(super::locate_bit_flip(40, s), Some((j, 1 << b)));
            }
        }
        assert_eq!(super::locate_bit_flip(40, 0), None);
    }

    #[test]
    fn check_value() {
        // The standard check value of CRC-32/ISO-HDLC.
        assert_eq!(super::crc32(b"123456789"), 0xCBF4_3926);
        let mut c = super::Crc32::new();
        c.update(b"1234");
        c.update(b"56789");
        assert_eq!(c.finish(), 0xCBF4_3926);
    }
}
