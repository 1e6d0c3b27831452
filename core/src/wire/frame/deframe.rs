//! The receiving side: a byte stream split at its delimiters, each piece
//! read through its header (repaired when one byte of it is damaged) and
//! decoded ([`super::repair`]).

use super::repair::{decode, Received};
use super::*;

/// What the decoder repaired in a frame: a line's damage, counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Damage {
    /// Bytes corrected in place (substituted on the line).
    pub substituted: u8,
    /// Bytes the line dropped, rebuilt.
    pub dropped: u8,
    /// Bytes the line duplicated, removed.
    pub duplicated: u8,
}

impl Damage {
    /// Nothing repaired.
    pub fn is_none(&self) -> bool {
        *self == Damage::default()
    }

    /// Both damages, counted together.
    pub fn plus(self, other: Damage) -> Damage {
        Damage {
            substituted: self.substituted.saturating_add(other.substituted),
            dropped: self.dropped.saturating_add(other.dropped),
            duplicated: self.duplicated.saturating_add(other.duplicated),
        }
    }
}

/// A frame the deframer completed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Arrived<'a> {
    /// The payload, its CRC checked.
    pub payload: &'a [u8],
    /// Whether anything was repaired.
    pub repaired: bool,
    /// What was repaired.
    pub damage: Damage,
    /// Parity bytes the frame carried (a block: each segment).
    pub parity: u8,
    /// Segments of the block it came in (`super::block`); 0: a frame.
    pub segments: u8,
}

/// A piece decoded as a frame: its payload's length, what was repaired,
/// its parity and what it carries.
#[derive(Clone, Copy, Debug)]
pub(in crate::wire) struct Completed {
    pub(in crate::wire) n: usize,
    pub(in crate::wire) damage: Damage,
    pub(in crate::wire) parity: usize,
    pub(in crate::wire) kind: FrameKind,
}

/// Reassembles frames from a byte stream, one byte at a time, correcting
/// what the code allows (see the module's documentation).
pub struct Deframer {
    buf: [u8; MAX_FRAME],
    len: usize,
    /// Dropping bytes until the next delimiter (after an oversized frame).
    skipping: bool,
    /// The codeword being tried.
    work: [u8; MAX_CODEWORD + 2],
}

impl Default for Deframer {
    fn default() -> Self {
        Self::new()
    }
}

impl Deframer {
    /// An empty deframer.
    pub const fn new() -> Self {
        Deframer { buf: [0; MAX_FRAME], len: 0, skipping: false, work: [0; MAX_CODEWORD + 2] }
    }

    /// Feeds one byte. `Ok(Some(payload))` when it completed a good frame
    /// (whole or repaired); `Err` when it completed a bad one; `Ok(None)`
    /// otherwise.
    pub fn push(&mut self, byte: u8) -> Result<Option<&[u8]>, DeframeError> {
        Ok(self.push_frame(byte)?.map(|f| f.payload))
    }

    /// As [`Deframer::push`], saying also what was repaired: what a sender
    /// sizing frames for the line wants to know.
    pub fn push_frame(&mut self, byte: u8) -> Result<Option<Arrived<'_>>, DeframeError> {
        let Some(len) = self.accept(byte)? else { return Ok(None) };
        let c = self.complete(len)?;
        // A block's descriptor is for a block deframer (`super::block`).
        if c.kind == FrameKind::Descriptor {
            return Err(DeframeError::Header);
        }
        Ok(Some(self.arrived(c)))
    }

    /// Takes one byte: the length of the piece a delimiter ended (`None`
    /// for any other byte, an idle line's empty piece or the tail of an
    /// oversized one).
    pub(in crate::wire) fn accept(&mut self, byte: u8) -> Result<Option<usize>, DeframeError> {
        if byte != 0 {
            if self.skipping {
                return Ok(None);
            }
            if self.len == self.buf.len() {
                self.len = 0;
                self.skipping = true;
                return Err(DeframeError::Oversized);
            }
            self.buf[self.len] = byte;
            self.len += 1;
            return Ok(None);
        }
        let len = core::mem::take(&mut self.len);
        if core::mem::take(&mut self.skipping) || len == 0 {
            return Ok(None);
        }
        Ok(Some(len))
    }

    /// The bytes of the piece that ended, `len` long.
    pub(in crate::wire) fn piece(&self, len: usize) -> &[u8] {
        self.buf.get(..len).unwrap_or(&[])
    }

    /// Takes back a piece of `len` bytes as unfinished, with `byte` in
    /// place of the delimiter that ended it (a substituted zero).
    pub(in crate::wire) fn resume(&mut self, len: usize, byte: u8) {
        if len < self.buf.len() {
            self.buf[len] = byte;
            self.len = len + 1;
        }
    }

    /// The codeword buffer, for decoding a block's segments.
    pub(in crate::wire) fn work(&mut self) -> &mut [u8] {
        &mut self.work
    }

    /// Decodes the piece of `len` bytes as a frame; [`Deframer::arrived`]
    /// gives what it carried.
    pub(in crate::wire) fn complete(&mut self, len: usize) -> Result<Completed, DeframeError> {
        if self.buf.first() == Some(&PLAIN) {
            let n = self.plain(len)?;
            return Ok(Completed { n, damage: Damage::default(), parity: 0, kind: FrameKind::Frame });
        }
        let (n, damage, parity, kind) = self.finish(len)?;
        Ok(Completed { n, damage, parity, kind })
    }

    /// The frame [`Deframer::complete`] decoded.
    pub(in crate::wire) fn arrived(&self, c: Completed) -> Arrived<'_> {
        let payload = if c.parity == 0 { self.buf.get(1..1 + c.n) } else { self.work.get(..c.n) };
        Arrived {
            payload: payload.unwrap_or(&[]),
            repaired: !c.damage.is_none(),
            damage: c.damage,
            parity: c.parity as u8,
            segments: 0,
        }
    }

    /// Decodes `range` of the last piece as a block's segment: `p` of its
    /// `n` bytes parity, zeros sent as `h`; the corrected data bytes are at
    /// the start of [`Deframer::work`].
    pub(in crate::wire) fn segment(
        &mut self,
        range: core::ops::Range<usize>,
        (p, n, h): (usize, usize, u8),
    ) -> Result<Damage, DeframeError> {
        let bytes = self.buf.get(range).ok_or(DeframeError::Short)?;
        decode(Received { bytes, h }, p, n, &mut self.work, false).map(|(_, damage)| damage)
    }

    /// Decodes a frame without parity in place: its payload's length (from
    /// `buf[1]` on).
    fn plain(&mut self, len: usize) -> Result<usize, DeframeError> {
        let body = self.buf.get_mut(1..len).ok_or(DeframeError::Short)?;
        let n = cobs_decode_in_place(body).ok_or(DeframeError::Checksum)?;
        // An empty payload is no message.
        if n <= 4 {
            return Err(DeframeError::Short);
        }
        let (payload, crc) = body.get(..n).ok_or(DeframeError::Short)?.split_at(n - 4);
        if crc32(payload).to_le_bytes() != [crc[0], crc[1], crc[2], crc[3]] {
            return Err(DeframeError::Checksum);
        }
        Ok(n - 4)
    }

    /// Decodes the `len` bytes received: the payload's length (at the start
    /// of `work`), what was repaired and the parity count.
    fn finish(&mut self, len: usize) -> Result<(usize, Damage, usize, FrameKind), DeframeError> {
        let frame = self.buf.get(..len).ok_or(DeframeError::Oversized)?;
        let mut error = DeframeError::Header;
        for cand in header_candidates(frame).iter().flatten() {
            let Some(body) = frame.get(cand.body..) else { continue };
            let word = Received { bytes: body, h: cand.h };
            match decode(word, cand.parity, cand.n, &mut self.work, true) {
                Ok((payload, damage)) => return Ok((payload, cand.damage.plus(damage), cand.parity, cand.kind)),
                Err(e) => error = e,
            }
        }
        Err(error)
    }
}

/// Whether `piece` (the bytes before a delimiter) reads as a whole coded
/// frame or descriptor: its header's check holds, its code names a parity,
/// and its length fits the codeword's within two edits.
pub(in crate::wire) fn reads_whole(piece: &[u8]) -> bool {
    let Some(&[c, h, n, k]) = piece.first_chunk::<HEADER>() else { return false };
    let coded = |base: u8| c >= base && usize::from(c - base) * 2 <= MAX_PARITY;
    let named = coded(CODE_BASE) && c < DESCRIPTOR_BASE || coded(DESCRIPTOR_BASE);
    c ^ h ^ n ^ k ^ CHECK == 0 && named && (usize::from(n) + HEADER).abs_diff(piece.len()) <= 2
}

/// A reading of a frame's header: the codeword's parity, replacement value
/// and length, where the codeword starts, and what was repaired to read it.
#[derive(Clone, Copy)]
struct HeaderReading {
    kind: FrameKind,
    parity: usize,
    h: u8,
    n: usize,
    body: usize,
    damage: Damage,
}

/// The readings of the header at the start of `frame` worth a try, best
/// first: as sent when its check holds; else with one byte rebuilt from the
/// others (substituted), one byte inserted (dropped: its value follows from
/// the check) or one of two equal bytes removed (duplicated). A reading
/// must name a parity, a codeword length near what follows, and a
/// non-zero replacement.
fn header_candidates(frame: &[u8]) -> [Option<HeaderReading>; 13] {
    let mut out = [None; 13];
    let Some(&[c, h, n, k]) = frame.first_chunk::<HEADER>() else { return out };
    let make = |[c, h, n]: [u8; 3], body: usize, damage: Damage| {
        let (kind, base) =
            if c >= DESCRIPTOR_BASE { (FrameKind::Descriptor, DESCRIPTOR_BASE) } else { (FrameKind::Frame, CODE_BASE) };
        let p = usize::from(c.wrapping_sub(base)) * 2;
        let n = usize::from(n);
        let rest = frame.len().checked_sub(body)?;
        let fits = c >= CODE_BASE && p <= MAX_PARITY && h != 0 && n >= p + 5 && n <= MAX_CODEWORD;
        // Longer: a lost delimiter (the next frame came along), unless the
        // header was read through an edit (then one damage is spent).
        let near = if body == HEADER { rest + 2 >= n } else { rest.abs_diff(n) <= 2 };
        (fits && near).then_some(HeaderReading { kind, parity: p, h, n, body, damage })
    };
    // A header whose check holds may still be a shifted one (a dropped
    // byte equal to the next): the edits are tried after it.
    if c ^ h ^ n ^ k ^ CHECK == 0 {
        out[0] = make([c, h, n], HEADER, Damage::default());
    } else {
        let sub = Damage { substituted: 1, ..Damage::default() };
        let rebuilt = [[c, h, k ^ c ^ h ^ CHECK], [c, k ^ c ^ n ^ CHECK, n], [k ^ h ^ n ^ CHECK, h, n], [c, h, n]];
        for (slot, head) in out.iter_mut().zip(rebuilt) {
            *slot = make(head, HEADER, sub);
        }
    }
    // The edits only when no reading above names a codeword of about the
    // length received: a shifted header rarely does, and each reading tried
    // costs a search.
    if out.iter().flatten().any(|r| (frame.len() - r.body).abs_diff(r.n) <= 2) {
        return out;
    }
    // A byte dropped at `j`: the three received and the missing one.
    let drop = Damage { dropped: 1, ..Damage::default() };
    let three = [c, h, n];
    for j in 0..HEADER {
        let missing = three.iter().fold(CHECK, |acc, &b| acc ^ b);
        let mut head = [0u8; HEADER];
        let mut from = three.iter();
        for (i, b) in head.iter_mut().enumerate() {
            *b = if i == j { missing } else { from.next().copied().unwrap_or(0) };
        }
        out[4 + j] = make([head[0], head[1], head[2]], HEADER - 1, drop);
    }
    // A byte duplicated at `j`: two equal bytes, one removed.
    let dup = Damage { duplicated: 1, ..Damage::default() };
    if let Some(five) = frame.first_chunk::<{ HEADER + 1 }>() {
        for j in 0..HEADER {
            if five[j] != five[j + 1] {
                continue;
            }
            let mut head = [0u8; HEADER];
            let mut from = five.iter().enumerate().filter(|&(i, _)| i != j + 1).map(|(_, &b)| b);
            for b in head.iter_mut() {
                *b = from.next().unwrap_or(0);
            }
            if head.iter().fold(CHECK, |acc, &b| acc ^ b) == 0 {
                out[8 + j] = make([head[0], head[1], head[2]], HEADER + 1, dup);
            }
        }
    }
    out
}
