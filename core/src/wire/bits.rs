//! Bit-level writer and reader over caller-provided byte slices.

/// The bit writer ran out of room.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Overflow;

/// The bit reader ran out of bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Truncated;

/// Writes bits most-significant first.
pub struct BitWriter<'a> {
    buf: &'a mut [u8],
    bits: usize,
}

impl<'a> BitWriter<'a> {
    /// A writer at the start of `buf`.
    pub fn new(buf: &'a mut [u8]) -> Self {
        BitWriter { buf, bits: 0 }
    }

    /// Bits written so far.
    pub fn bit_len(&self) -> usize {
        self.bits
    }

    /// Bytes used (the last one padded with zeros).
    pub fn byte_len(&self) -> usize {
        self.bits.div_ceil(8)
    }

    /// Writes the low `n` bits of `value` (n <= 32).
    pub fn write(&mut self, value: u32, n: u32) -> Result<(), Overflow> {
        if n > 32 || self.bits + n as usize > self.buf.len() * 8 {
            return Err(Overflow);
        }
        for i in (0..n).rev() {
            let bit = (value >> i) & 1;
            let byte = self.bits / 8;
            let slot = self.buf.get_mut(byte).ok_or(Overflow)?;
            if self.bits.is_multiple_of(8) {
                *slot = 0;
            }
            *slot |= (bit as u8) << (7 - self.bits % 8);
            self.bits += 1;
        }
        Ok(())
    }

    /// Writes `value` (below 2^48) as a Golomb-Rice code with parameter `k`
    /// (at most [`MAX_RICE_K`]): the quotient `value >> k` in unary (ones then
    /// a zero), then the low `k` bits.
    pub fn write_rice(&mut self, value: u64, k: u32) -> Result<(), Overflow> {
        if k > MAX_RICE_K || value >> 48 != 0 {
            return Err(Overflow);
        }
        let q = value >> k;
        // Long quotients escape: 32 ones, then the value in 48 bits.
        if q >= 32 {
            self.write(u32::MAX, 32)?;
            self.write((value >> 32) as u32 & 0xFFFF, 16)?;
            return self.write(value as u32, 32);
        }
        let q = q as u32;
        if q > 0 {
            self.write(u32::MAX >> (32 - q), q)?;
        }
        self.write(0, 1)?;
        self.write((value & ((1u64 << k) - 1)) as u32, k)
    }
}

/// Largest Golomb-Rice parameter.
pub const MAX_RICE_K: u32 = 24;

/// Bits a Golomb-Rice code of `value` with parameter `k` takes.
pub fn rice_len(value: u64, k: u32) -> usize {
    let q = value >> k.min(MAX_RICE_K);
    if q >= 32 {
        80
    } else {
        q as usize + 1 + k as usize
    }
}

/// Reads bits most-significant first.
pub struct BitReader<'a> {
    buf: &'a [u8],
    bits: usize,
}

impl<'a> BitReader<'a> {
    /// A reader at the start of `buf`.
    pub fn new(buf: &'a [u8]) -> Self {
        BitReader { buf, bits: 0 }
    }

    /// Bits left.
    pub fn remaining(&self) -> usize {
        self.buf.len() * 8 - self.bits
    }

    /// Reads `n` bits (n <= 32).
    pub fn read(&mut self, n: u32) -> Result<u32, Truncated> {
        if n > 32 || n as usize > self.remaining() {
            return Err(Truncated);
        }
        let mut v = 0u32;
        for _ in 0..n {
            let byte = self.buf.get(self.bits / 8).copied().ok_or(Truncated)?;
            v = (v << 1) | u32::from((byte >> (7 - self.bits % 8)) & 1);
            self.bits += 1;
        }
        Ok(v)
    }

    /// Reads a Golomb-Rice code with parameter `k` (at most [`MAX_RICE_K`]).
    pub fn read_rice(&mut self, k: u32) -> Result<u64, Truncated> {
        if k > MAX_RICE_K {
            return Err(Truncated);
        }
        let mut q = 0u32;
        while q < 32 && self.read(1)? == 1 {
            q += 1;
        }
        if q == 32 {
            let hi = u64::from(self.read(16)?);
            let lo = u64::from(self.read(32)?);
            return Ok((hi << 32) | lo);
        }
        let low = u64::from(self.read(k)?);
        Ok((u64::from(q) << k) | low)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_bits_and_rice() {
        let mut buf = [0u8; 256];
        let mut w = BitWriter::new(&mut buf);
        let values = [0u64, 1, 2, 3, 7, 100, 1000, 123_456_789, (1 << 48) - 1, (1 << 40) + 5];
        for (i, v) in values.iter().enumerate() {
            w.write(i as u32, 5).unwrap();
            let k = (i as u32 * 5) % (MAX_RICE_K + 1);
            let before = w.bit_len();
            w.write_rice(*v, k).unwrap();
            assert_eq!(w.bit_len() - before, rice_len(*v, k));
        }
        let n = w.byte_len();
        let mut r = BitReader::new(&buf[..n]);
        for (i, v) in values.iter().enumerate() {
            assert_eq!(r.read(5).unwrap(), i as u32);
            assert_eq!(r.read_rice((i as u32 * 5) % (MAX_RICE_K + 1)).unwrap(), *v);
        }
        assert!(r.remaining() < 8);
    }

    #[test]
    fn overflow_and_truncation_are_errors() {
        let mut buf = [0u8; 1];
        let mut w = BitWriter::new(&mut buf);
        w.write(0xAB, 8).unwrap();
        assert_eq!(w.write(1, 1), Err(Overflow));
        let mut r = BitReader::new(&[0xFF]);
        assert_eq!(r.read_rice(0), Err(Truncated));
        let mut big = [0u8; 64];
        let mut w = BitWriter::new(&mut big);
        assert_eq!(w.write(0, 33), Err(Overflow));
        assert_eq!(w.write_rice(1 << 48, 0), Err(Overflow));
        assert_eq!(w.write_rice(1, MAX_RICE_K + 1), Err(Overflow));
        assert_eq!(BitReader::new(&[0; 8]).read(33), Err(Truncated));
    }
}
