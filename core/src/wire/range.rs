//! An adaptive binary range coder (the kind LZMA uses): each yes/no
//! decision is coded with a probability that follows what the same
//! decision did before, so a decision that is nearly always the same costs
//! a small fraction of a bit. Symbols of several bits are coded as a binary
//! tree of decisions ([`RangeEncoder::tree`]).
//!
//! The encoder writes into a caller's buffer and never allocates; the
//! decoder reads a byte slice, never reads past it (missing bytes read as
//! zero and are reported by [`RangeDecoder::finish`]) and never panics, on
//! any input.

/// Probabilities are `p / 2^11` that the next bit is 0.
const PROB_BITS: u32 = 11;
const PROB_ONE: u32 = 1 << PROB_BITS;
/// How fast a probability follows its decisions (1/32 of the gap per bit).
const MOVE_BITS: u32 = 5;
const TOP: u32 = 1 << 24;

/// A probability before any decision: even odds.
pub const PROB_INIT: u16 = (PROB_ONE / 2) as u16;

/// The output buffer is full.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Full;

/// Codes decisions into a buffer.
pub struct RangeEncoder<'a> {
    out: &'a mut [u8],
    at: usize,
    low: u64,
    range: u32,
    cache: u8,
    pending: u32,
    /// The first byte out is always zero: it is not written.
    first: bool,
}

impl<'a> RangeEncoder<'a> {
    /// An encoder writing into `out`.
    pub fn new(out: &'a mut [u8]) -> Self {
        RangeEncoder { out, at: 0, low: 0, range: u32::MAX, cache: 0, pending: 1, first: true }
    }

    fn emit(&mut self, b: u8) -> Result<(), Full> {
        if core::mem::take(&mut self.first) {
            return Ok(());
        }
        *self.out.get_mut(self.at).ok_or(Full)? = b;
        self.at += 1;
        Ok(())
    }

    fn shift_low(&mut self) -> Result<(), Full> {
        if (self.low as u32) < 0xFF00_0000 || (self.low >> 32) != 0 {
            let carry = (self.low >> 32) as u8;
            let mut byte = self.cache;
            while self.pending > 0 {
                self.emit(byte.wrapping_add(carry))?;
                byte = 0xFF;
                self.pending -= 1;
            }
            self.cache = (self.low >> 24) as u8;
        }
        self.pending += 1;
        self.low = (self.low & 0x00FF_FFFF) << 8;
        Ok(())
    }

    fn normalize(&mut self) -> Result<(), Full> {
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low()?;
        }
        Ok(())
    }

    /// Codes `bit` with probability `p` (then adapted).
    pub fn bit(&mut self, p: &mut u16, bit: bool) -> Result<(), Full> {
        let bound = (self.range >> PROB_BITS) * u32::from(*p);
        if bit {
            self.low += u64::from(bound);
            self.range -= bound;
            *p -= *p >> MOVE_BITS;
        } else {
            self.range = bound;
            *p += ((PROB_ONE - u32::from(*p)) >> MOVE_BITS) as u16;
        }
        self.normalize()
    }

    /// Codes the low `bits` bits of `value` at even odds, high bit first.
    pub fn direct(&mut self, value: u64, bits: u32) -> Result<(), Full> {
        for i in (0..bits).rev() {
            self.range >>= 1;
            if (value >> i) & 1 == 1 {
                self.low += u64::from(self.range);
            }
            self.normalize()?;
        }
        Ok(())
    }

    /// Codes the low `bits` bits of `value` as a binary tree of decisions,
    /// high bit first, with the probabilities `probs` (at least `2^bits`).
    pub fn tree(&mut self, probs: &mut [u16], value: u32, bits: u32) -> Result<(), Full> {
        let mut node = 1usize;
        for i in (0..bits).rev() {
            let bit = (value >> i) & 1 == 1;
            self.bit(probs.get_mut(node).ok_or(Full)?, bit)?;
            node = (node << 1) | usize::from(bit);
        }
        Ok(())
    }

    /// Bytes the stream takes if it ends now ([`RangeEncoder::finish`]).
    pub fn len_if_finished(&self) -> usize {
        self.at + self.pending as usize + 4 - usize::from(self.first)
    }

    /// Ends the stream; returns its length in bytes.
    pub fn finish(mut self) -> Result<usize, Full> {
        for _ in 0..5 {
            self.shift_low()?;
        }
        Ok(self.at)
    }
}

/// Decodes what a [`RangeEncoder`] coded, with the same probabilities.
pub struct RangeDecoder<'a> {
    input: &'a [u8],
    at: usize,
    range: u32,
    code: u32,
}

impl<'a> RangeDecoder<'a> {
    /// A decoder of `input`.
    pub fn new(input: &'a [u8]) -> Self {
        let mut d = RangeDecoder { input, at: 0, range: u32::MAX, code: 0 };
        for _ in 0..4 {
            d.code = (d.code << 8) | u32::from(d.byte());
        }
        d
    }

    fn byte(&mut self) -> u8 {
        let b = self.input.get(self.at).copied().unwrap_or(0);
        self.at = self.at.saturating_add(1);
        b
    }

    fn normalize(&mut self) {
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | u32::from(self.byte());
        }
    }

    /// Decodes a bit coded with probability `p` (then adapted).
    pub fn bit(&mut self, p: &mut u16) -> bool {
        let bound = (self.range >> PROB_BITS) * u32::from(*p);
        let bit = self.code >= bound;
        if bit {
            self.code -= bound;
            self.range -= bound;
            *p -= *p >> MOVE_BITS;
        } else {
            self.range = bound;
            *p += ((PROB_ONE - u32::from(*p)) >> MOVE_BITS) as u16;
        }
        self.normalize();
        bit
    }

    /// Decodes `bits` bits at even odds, high bit first.
    pub fn direct(&mut self, bits: u32) -> u64 {
        let mut v = 0u64;
        for _ in 0..bits {
            self.range >>= 1;
            let bit = self.code >= self.range;
            if bit {
                self.code -= self.range;
            }
            v = (v << 1) | u64::from(bit);
            self.normalize();
        }
        v
    }

    /// Decodes a `bits`-bit value coded by [`RangeEncoder::tree`]; `None`
    /// when `probs` is shorter than `2^bits`.
    pub fn tree(&mut self, probs: &mut [u16], bits: u32) -> Option<u32> {
        let mut node = 1usize;
        for _ in 0..bits {
            let bit = self.bit(probs.get_mut(node)?);
            node = (node << 1) | usize::from(bit);
        }
        Some((node - (1 << bits)) as u32)
    }

    /// Whether exactly the input was read: `Err(true)` when the stream ran
    /// past its end (truncated), `Err(false)` when bytes are left over.
    pub fn finish(&self) -> Result<(), bool> {
        match self.at.cmp(&self.input.len()) {
            core::cmp::Ordering::Equal => Ok(()),
            core::cmp::Ordering::Greater => Err(true),
            core::cmp::Ordering::Less => Err(false),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rng(mut s: u64) -> impl FnMut() -> u64 {
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        }
    }

    #[test]
    fn decodes_what_was_coded_in_exactly_its_bytes() {
        let mut next = rng(7);
        for len in [0usize, 1, 3, 50, 2000] {
            let symbols: std::vec::Vec<(u32, bool, u64)> =
                (0..len).map(|_| ((next() % 8) as u32, next() % 10 < 8, next() % 1000)).collect();
            let mut out = [0u8; 8192];
            let (mut p, mut t) = ([PROB_INIT; 4], [PROB_INIT; 8]);
            let mut e = RangeEncoder::new(&mut out);
            for &(s, b, d) in &symbols {
                e.bit(&mut p[(s % 4) as usize], b).unwrap();
                e.tree(&mut t, s, 3).unwrap();
                e.direct(d, 10).unwrap();
            }
            let predicted = e.len_if_finished();
            let n = e.finish().unwrap();
            assert_eq!(n, predicted, "length {len}");
            let (mut p, mut t) = ([PROB_INIT; 4], [PROB_INIT; 8]);
            let mut d = RangeDecoder::new(&out[..n]);
            for &(s, b, v) in &symbols {
                assert_eq!(d.bit(&mut p[(s % 4) as usize]), b);
                assert_eq!(d.tree(&mut t, 3), Some(s));
                assert_eq!(d.direct(10), v);
            }
            assert_eq!(d.finish(), Ok(()));
            if n > 0 {
                let mut d = RangeDecoder::new(&out[..n - 1]);
                let (mut p, mut t) = ([PROB_INIT; 4], [PROB_INIT; 8]);
                for &(s, _, _) in &symbols {
                    d.bit(&mut p[(s % 4) as usize]);
                    d.tree(&mut t, 3);
                    d.direct(10);
                }
                assert_eq!(d.finish(), Err(true), "a byte short");
            }
        }
    }

    #[test]
    fn skewed_decisions_cost_little_and_garbage_never_panics() {
        let mut out = [0u8; 1024];
        let mut p = PROB_INIT;
        let mut e = RangeEncoder::new(&mut out);
        for i in 0..4000 {
            e.bit(&mut p, i % 100 == 0).unwrap();
        }
        let n = e.finish().unwrap();
        assert!(n < 60, "4000 decisions of 1% took {n} bytes");
        assert_eq!(RangeEncoder::new(&mut [0u8; 2]).direct(u64::MAX, 64), Err(Full));
        let mut next = rng(3);
        for _ in 0..2000 {
            let bytes: std::vec::Vec<u8> = (0..(next() % 40)).map(|_| next() as u8).collect();
            let mut d = RangeDecoder::new(&bytes);
            let mut t = [PROB_INIT; 64];
            for _ in 0..50 {
                let _ = d.tree(&mut t, 6);
                let _ = d.direct(7);
            }
            let _ = d.finish();
            assert_eq!(d.tree(&mut [PROB_INIT; 2], 3), None);
        }
    }
}
