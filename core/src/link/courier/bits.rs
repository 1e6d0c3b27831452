//! Which units of a message are held: one bit each, with the scans a
//! window and an acknowledgement need.

use super::MAX_UNITS;

/// Units held: one bit each.
#[derive(Clone, Copy)]
pub(super) struct Bits([u32; MAX_UNITS / 32]);

impl Bits {
    pub(super) const fn new() -> Self {
        Bits([0; MAX_UNITS / 32])
    }
    pub(super) fn get(&self, k: usize) -> bool {
        self.0.get(k / 32).is_some_and(|w| w & (1 << (k % 32)) != 0)
    }
    pub(super) fn set(&mut self, k: usize) {
        if let Some(w) = self.0.get_mut(k / 32) {
            *w |= 1 << (k % 32);
        }
    }
    pub(super) fn all(&self, from: usize, to: usize) -> bool {
        (from..to).all(|k| self.get(k))
    }
    /// The first unit at or after `from`, below `n`, held (`n` when none
    /// is).
    pub(super) fn first_set(&self, from: usize, n: usize) -> usize {
        let mut k = from;
        while k < n {
            match self.0.get(k / 32) {
                Some(&0) if k.is_multiple_of(32) => k += 32,
                Some(&w) if w & (1 << (k % 32)) == 0 => k += 1,
                _ => return k.min(n),
            }
        }
        n
    }
    /// The first unit at or after `from`, below `n`, not held (`n` when
    /// all are).
    pub(super) fn first_clear(&self, from: usize, n: usize) -> usize {
        let mut k = from;
        while k < n {
            match self.0.get(k / 32) {
                Some(&w) if k.is_multiple_of(32) && w == u32::MAX => k += 32,
                Some(&w) if w & (1 << (k % 32)) != 0 => k += 1,
                _ => return k,
            }
        }
        n
    }
}
