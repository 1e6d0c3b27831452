//! Memory that serves several stages in turn, by ownership. A board
//! declares a robot's memory once, as regions of words; each stage carves
//! typed buffers out of a region it owns (plain-integer types only, any
//! value valid: [`bytemuck::Pod`]) and gives them back as words when it
//! ends, and the next stage carves its own out of them. Nothing is reached
//! through a pointer and no stage depends on another's call order: the
//! borrow checker sees each hand-over as a move.

use bytemuck::Pod;

/// A region too small, or a buffer whose size or alignment does not fit a
/// region of words.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RegionError {
    /// `need` words were asked of a region holding `have`.
    Short {
        /// Words asked.
        need: usize,
        /// Words left.
        have: usize,
    },
    /// A type aligned to more than a word, or a byte count that overflows.
    Layout,
}

impl core::fmt::Display for RegionError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RegionError::Short { need, have } => write!(f, "memory region short: {need} words asked, {have} left"),
            RegionError::Layout => f.write_str("a buffer's type does not fit a region of words"),
        }
    }
}

/// Words needed for `n` values of `T`.
pub const fn words_for<T>(n: usize) -> usize {
    (n * core::mem::size_of::<T>()).div_ceil(4)
}

/// Words of a region, carved from the front.
pub struct Region<'a> {
    words: &'a mut [u32],
}

impl<'a> Region<'a> {
    /// All of `words`.
    pub fn new(words: &'a mut [u32]) -> Self {
        Region { words }
    }

    /// Words left.
    pub fn len(&self) -> usize {
        self.words.len()
    }

    /// Whether no word is left.
    pub fn is_empty(&self) -> bool {
        self.words.is_empty()
    }

    /// The next `n` words.
    pub fn take_words(&mut self, n: usize) -> Result<&'a mut [u32], RegionError> {
        let have = self.words.len();
        if n > have {
            return Err(RegionError::Short { need: n, have });
        }
        let (head, tail) = core::mem::take(&mut self.words).split_at_mut(n);
        self.words = tail;
        Ok(head)
    }

    /// The next `n` values of `T` (their bytes rounded up to whole words),
    /// as they are in memory (any value is a valid `T`).
    pub fn take<T: Pod>(&mut self, n: usize) -> Result<&'a mut [T], RegionError> {
        let bytes = n.checked_mul(core::mem::size_of::<T>()).ok_or(RegionError::Layout)?;
        if core::mem::align_of::<T>() > 4 {
            return Err(RegionError::Layout);
        }
        let words = self.take_words(bytes.div_ceil(4))?;
        let raw: &mut [u8] = bytemuck::cast_slice_mut(words);
        let raw = raw.get_mut(..bytes).ok_or(RegionError::Layout)?;
        bytemuck::try_cast_slice_mut(raw).map_err(|_| RegionError::Layout)
    }

    /// What is left.
    pub fn into_words(self) -> &'a mut [u32] {
        self.words
    }
}

/// The whole words of a buffer carved from a region (given back for the
/// next stage); a buffer whose start is not word-aligned gives none.
pub fn words_of<T: Pod>(buffer: &mut [T]) -> &mut [u32] {
    let raw: &mut [u8] = bytemuck::cast_slice_mut(buffer);
    let whole = raw.len() / 4 * 4;
    match raw.get_mut(..whole) {
        Some(raw) => bytemuck::try_cast_slice_mut(raw).unwrap_or_default(),
        None => &mut [],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn carves_in_order_and_gives_back_whole_words() {
        let mut mem = [0u32; 10];
        let mut r = Region::new(&mut mem);
        let a: &mut [u16] = r.take(3).unwrap();
        assert_eq!(a.len(), 3);
        a.fill(7);
        let b: &mut [[u8; 6]] = r.take(2).unwrap();
        assert_eq!(b.len(), 2);
        assert_eq!(r.len(), 5);
        assert_eq!(r.take::<u32>(6), Err(RegionError::Short { need: 6, have: 5 }));
        assert_eq!(r.take::<u64>(1), Err(RegionError::Layout));
        assert_eq!(words_of(a).len(), 1);
        assert_eq!(words_of(b).len(), 3);
        assert_eq!(r.into_words().len(), 5);
        assert_eq!(mem[0], 0x0007_0007);
    }
}
