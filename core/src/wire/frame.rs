//! Framing with forward error correction. A frame on the line is
//!
//! ```text
//! [code] [h] [n] [check]  W  0x00
//! ```
//!
//! where `W` is a Reed-Solomon codeword of `n` bytes ([`super::rs`]):
//! `payload ++ CRC-32(payload) ++ p parity bytes`, with every zero byte
//! replaced by `h`, a non-zero value the codeword does not contain. So a
//! zero always ends a frame and a receiver resynchronises on the next one
//! after any line error, as with COBS, but a substituted byte stays one
//! symbol error (a COBS code byte hit garbles the rest of its frame). `code`
//! says `p` (`0xC0 + p/2`), `check` is `code ^ h ^ n ^ 0xA5`: a header with
//! one bad byte is rebuilt from the other three.
//!
//! The receiver corrects up to `p/2` substituted bytes; a frame whose
//! length is off because the line dropped or duplicated a byte (or two) is
//! repaired by trying the edit at each position against the code, each try
//! costing a few field operations on syndromes shifted in place (the
//! syndromes of the whole received word are computed once). A try must
//! leave one parity equation unused, and the CRC-32 must hold: a wrong
//! repair passes both with probability about `2^-40` per try.
//!
//! A frame without parity (`p = 0`, a clean line's) is `0xBF` and
//! `COBS(payload ++ CRC-32)`: up to [`MAX_PAYLOAD`] bytes, a CRC and nothing
//! to correct. Senders that know the line choose `p` per frame
//! ([`encode_frame_parity`]); the others use [`DEFAULT_PARITY`].

use super::crc::crc32;
use super::rs::{self, alpha_pow, mul, MAX_PARITY};

/// Bytes before the codeword: code, replacement, length, check.
pub const HEADER: usize = 4;
/// Longest codeword (so that a replacement value always exists).
pub const MAX_CODEWORD: usize = 253;
/// Largest payload of a frame with parity (less the parity).
pub const MAX_CODED_PAYLOAD: usize = MAX_CODEWORD - 4;
/// Largest payload of a frame (one without parity: a clean line's).
pub const MAX_PAYLOAD: usize = 512;
/// Largest frame on the line: a plain frame's kind, its COBS body (payload
/// and CRC, one code byte per 254), delimiter; longer than any coded one.
pub const MAX_FRAME: usize = 1 + cobs_len(MAX_PAYLOAD + 4) + 1;
/// Parity bytes of frames whose sender does not size them for the line
/// (two substituted bytes or one dropped byte repaired).
pub const DEFAULT_PARITY: usize = 4;
/// Longest codeword the deframer tries two edits on (the tries grow with
/// the square of the length; frames on a line that bad are short).
pub const PAIR_MAX: usize = 96;
/// Longest codeword whose pairs of edits may come with any number of
/// errors the parity allows (beyond, one at most: see `pairs`).
pub const PAIR_FULL: usize = 24;

const CODE_BASE: u8 = 0xC0;
/// First byte of a block's descriptor (`super::block`): `0xE0 + p/2`.
pub(super) const DESCRIPTOR_BASE: u8 = 0xE0;

/// What a coded frame carries: a message's payload, or the descriptor of
/// the block whose segments follow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum FrameKind {
    Frame,
    Descriptor,
}
const CHECK: u8 = 0xA5;
/// First byte of a frame without parity: COBS and a CRC-32, no correction.
const PLAIN: u8 = 0xBF;

/// The largest payload of a frame with `parity` parity bytes.
pub const fn max_payload(parity: usize) -> usize {
    if parity == 0 {
        MAX_PAYLOAD
    } else {
        MAX_CODED_PAYLOAD.saturating_sub(parity)
    }
}

/// COBS-encoded length of `n` bytes.
const fn cobs_len(n: usize) -> usize {
    n + n / 254 + 1
}

/// Bytes on the line of a frame of a `payload`-byte payload with `parity`
/// parity bytes, delimiter included.
pub const fn frame_len(payload: usize, parity: usize) -> usize {
    if parity == 0 {
        1 + cobs_len(payload + 4) + 1
    } else {
        HEADER + payload + 4 + parity + 1
    }
}

/// Why a frame could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// The payload exceeds [`max_payload`] of its parity.
    TooLong,
    /// The output buffer is too small.
    Buffer,
    /// An odd parity count or more than [`MAX_PARITY`].
    Parity,
}

/// Why bytes received did not make a frame. The decoder has already
/// resynchronised: feed it the next bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DeframeError {
    /// More bytes than the largest frame before a delimiter.
    Oversized,
    /// No header, or one with more than one bad byte.
    Header,
    /// Fewer bytes than a codeword's least.
    Short,
    /// More damage than the code repairs (the CRC or the code failed).
    Checksum,
}

impl core::fmt::Display for DeframeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            DeframeError::Oversized => "frame longer than the largest allowed",
            DeframeError::Header => "frame header damaged beyond repair",
            DeframeError::Short => "frame shorter than a codeword",
            DeframeError::Checksum => "frame damaged beyond repair",
        })
    }
}

impl core::error::Error for DeframeError {}

/// Encodes a message with `encode` (which writes its payload into a buffer
/// of [`MAX_PAYLOAD`] bytes and returns the length), then frames it into
/// `out` with [`DEFAULT_PARITY`]: the one place where "encode, then frame"
/// is written.
pub fn frame_with<E: From<FrameError>>(
    out: &mut [u8],
    encode: impl FnOnce(&mut [u8]) -> Result<usize, E>,
) -> Result<usize, E> {
    frame_with_parity(out, DEFAULT_PARITY, encode)
}

/// As [`frame_with`], with `parity` parity bytes.
pub fn frame_with_parity<E: From<FrameError>>(
    out: &mut [u8],
    parity: usize,
    encode: impl FnOnce(&mut [u8]) -> Result<usize, E>,
) -> Result<usize, E> {
    let mut payload = [0u8; MAX_PAYLOAD];
    let n = encode(&mut payload)?;
    Ok(encode_frame_parity(payload.get(..n).ok_or(FrameError::TooLong)?, parity, out)?)
}

/// Encodes one frame of `payload` into `out` (delimiter included) with
/// [`DEFAULT_PARITY`].
pub fn encode_frame(payload: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    encode_frame_parity(payload, DEFAULT_PARITY, out)
}

/// Encodes one frame of `payload` with `parity` parity bytes (even, at most
/// [`MAX_PARITY`]) into `out`; returns its length, delimiter included.
pub fn encode_frame_parity(payload: &[u8], parity: usize, out: &mut [u8]) -> Result<usize, FrameError> {
    if parity > MAX_PARITY || !parity.is_multiple_of(2) {
        return Err(FrameError::Parity);
    }
    if payload.len() > max_payload(parity) {
        return Err(FrameError::TooLong);
    }
    if parity == 0 {
        return encode_plain(payload, out);
    }
    encode_coded(payload, parity, CODE_BASE, out)
}

/// A coded frame of `payload`, its code byte `base + parity/2`.
pub(super) fn encode_coded(payload: &[u8], parity: usize, base: u8, out: &mut [u8]) -> Result<usize, FrameError> {
    if parity == 0 || parity > MAX_PARITY || !parity.is_multiple_of(2) {
        return Err(FrameError::Parity);
    }
    if payload.len() > max_payload(parity) {
        return Err(FrameError::TooLong);
    }
    let n = payload.len() + 4 + parity;
    let total = HEADER + n + 1;
    let frame = out.get_mut(..total).ok_or(FrameError::Buffer)?;
    let (head, rest) = frame.split_at_mut(HEADER);
    let (word, end) = rest.split_at_mut(n);
    let (data, par) = word.split_at_mut(n - parity);
    let (body, crc) = data.split_at_mut(payload.len());
    body.copy_from_slice(payload);
    crc.copy_from_slice(&crc32(payload).to_le_bytes());
    rs::encode(data, par).map_err(|_| FrameError::Parity)?;
    let code = base + (parity / 2) as u8;
    let len = n as u8;
    // The smallest value absent from the codeword whose check is non-zero.
    let mut seen = [false; 256];
    for &b in word.iter() {
        seen[usize::from(b)] = true;
    }
    let h = (1..=255u8).find(|&h| !seen[usize::from(h)] && code ^ h ^ len ^ CHECK != 0).ok_or(FrameError::TooLong)?;
    for b in word.iter_mut() {
        if *b == 0 {
            *b = h;
        }
    }
    head.copy_from_slice(&[code, h, len, code ^ h ^ len ^ CHECK]);
    end[0] = 0;
    Ok(total)
}

/// A frame without parity: its kind, then `COBS(payload ++ CRC-32)`.
fn encode_plain(payload: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    let mut raw = [0u8; MAX_PAYLOAD + 4];
    let n = payload.len();
    raw.get_mut(..n).ok_or(FrameError::TooLong)?.copy_from_slice(payload);
    raw[n..n + 4].copy_from_slice(&crc32(payload).to_le_bytes());
    *out.first_mut().ok_or(FrameError::Buffer)? = PLAIN;
    let len = cobs_encode(&raw[..n + 4], out.get_mut(1..).ok_or(FrameError::Buffer)?)?;
    *out.get_mut(1 + len).ok_or(FrameError::Buffer)? = 0;
    Ok(len + 2)
}

/// COBS-encodes `input` into `out`; returns the length (no delimiter).
fn cobs_encode(input: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    let (mut code_at, mut at, mut code) = (0usize, 1usize, 1u8);
    for &b in input {
        if b != 0 {
            *out.get_mut(at).ok_or(FrameError::Buffer)? = b;
            at += 1;
            code += 1;
        }
        if b == 0 || code == 0xFF {
            *out.get_mut(code_at).ok_or(FrameError::Buffer)? = code;
            code_at = at;
            at += 1;
            code = 1;
        }
    }
    *out.get_mut(code_at).ok_or(FrameError::Buffer)? = code;
    Ok(at)
}

/// Decodes COBS in place; the decoded length.
fn cobs_decode_in_place(buf: &mut [u8]) -> Option<usize> {
    let (mut read, mut write) = (0usize, 0usize);
    while let Some(&code) = buf.get(read) {
        read += 1;
        for _ in 1..code {
            let b = *buf.get(read)?;
            *buf.get_mut(write)? = b;
            write += 1;
            read += 1;
        }
        if code != 0xFF && read < buf.len() {
            *buf.get_mut(write)? = 0;
            write += 1;
        }
    }
    Some(write)
}

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
pub(super) struct Completed {
    pub(super) n: usize,
    pub(super) damage: Damage,
    pub(super) parity: usize,
    pub(super) kind: FrameKind,
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
    pub(super) fn accept(&mut self, byte: u8) -> Result<Option<usize>, DeframeError> {
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
    pub(super) fn piece(&self, len: usize) -> &[u8] {
        self.buf.get(..len).unwrap_or(&[])
    }

    /// Takes back a piece of `len` bytes as unfinished, with `byte` in
    /// place of the delimiter that ended it (a substituted zero).
    pub(super) fn resume(&mut self, len: usize, byte: u8) {
        if len < self.buf.len() {
            self.buf[len] = byte;
            self.len = len + 1;
        }
    }

    /// The codeword buffer, for decoding a block's segments.
    pub(super) fn work(&mut self) -> &mut [u8] {
        &mut self.work
    }

    /// Decodes the piece of `len` bytes as a frame; [`Deframer::arrived`]
    /// gives what it carried.
    pub(super) fn complete(&mut self, len: usize) -> Result<Completed, DeframeError> {
        if self.buf.first() == Some(&PLAIN) {
            let n = self.plain(len)?;
            return Ok(Completed { n, damage: Damage::default(), parity: 0, kind: FrameKind::Frame });
        }
        let (n, damage, parity, kind) = self.finish(len)?;
        Ok(Completed { n, damage, parity, kind })
    }

    /// The frame [`Deframer::complete`] decoded.
    pub(super) fn arrived(&self, c: Completed) -> Arrived<'_> {
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
    pub(super) fn segment(
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
pub(super) fn reads_whole(piece: &[u8]) -> bool {
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

/// The received codeword bytes, with the replacement value read as zero.
#[derive(Clone, Copy)]
pub(super) struct Received<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) h: u8,
}

impl Received<'_> {
    fn len(&self) -> usize {
        self.bytes.len()
    }

    fn at(&self, i: usize) -> u8 {
        match self.bytes.get(i) {
            Some(&b) if b != self.h => b,
            _ => 0,
        }
    }
}

/// An explanation of a frame's length: where the line dropped bytes
/// (a zero is inserted before received byte `i`) or duplicated them
/// (received byte `i` removed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Edit {
    None,
    Drop(usize),
    Dup(usize),
    Drops(usize, usize),
    Dups(usize, usize),
    /// Insert before `.0`, remove `.1`.
    DropDup(usize, usize),
}

impl Edit {
    /// Writes the edited word into `out`; its length.
    fn apply(self, r: Received<'_>, out: &mut [u8]) -> usize {
        let mut at = 0;
        let mut put = |b: u8, at: &mut usize| {
            if let Some(o) = out.get_mut(*at) {
                *o = b;
            }
            *at += 1;
        };
        for i in 0..=r.len() {
            let inserts = match self {
                Edit::Drop(a) | Edit::DropDup(a, _) => usize::from(a == i),
                Edit::Drops(a, b) => usize::from(a == i) + usize::from(b == i),
                _ => 0,
            };
            for _ in 0..inserts {
                put(0, &mut at);
            }
            let removed = match self {
                Edit::Dup(a) | Edit::DropDup(_, a) => a == i,
                Edit::Dups(a, b) => a == i || b == i,
                _ => false,
            };
            if i < r.len() && !removed {
                put(r.at(i), &mut at);
            }
        }
        at
    }

    /// Indices of the inserted bytes in the edited word (as many as the
    /// edit inserts; the rest zero).
    fn erasures(self) -> [usize; 2] {
        match self {
            Edit::Drop(a) => [a, 0],
            Edit::Drops(a, b) => [a, b + 1],
            Edit::DropDup(a, b) if b >= a => [a, 0],
            Edit::DropDup(a, _) => [a.saturating_sub(1), 0],
            _ => [0, 0],
        }
    }

    /// Bytes the edit inserts (erasures).
    fn inserted(self) -> usize {
        match self {
            Edit::Drop(_) | Edit::DropDup(..) => 1,
            Edit::Drops(..) => 2,
            _ => 0,
        }
    }

    /// Where the edit begins in the received word.
    fn position(self) -> usize {
        match self {
            Edit::None => 0,
            Edit::Drop(a) | Edit::Dup(a) => a,
            Edit::Drops(a, b) | Edit::Dups(a, b) | Edit::DropDup(a, b) => a.min(b),
        }
    }

    fn damage(self, substituted: usize) -> Damage {
        let (dropped, duplicated) = match self {
            Edit::None => (0, 0),
            Edit::Drop(_) => (1, 0),
            Edit::Dup(_) => (0, 1),
            Edit::Drops(..) => (2, 0),
            Edit::Dups(..) => (0, 2),
            Edit::DropDup(..) => (1, 1),
        };
        Damage { substituted: substituted.min(255) as u8, dropped, duplicated }
    }
}

/// Right-aligned prefix sums of the received word `r` (`m` bytes), per
/// syndrome `j < p`: `A_j(k) = Σ_{i<k} r_i α^(j (m-1-i))`. An edit shifts
/// the bytes after it by whole positions, which multiplies their share of
/// a syndrome by a power of `α^j`: so the syndromes of any edited word
/// follow from `A` at the edit's positions in `O(p)`.
#[derive(Clone, Copy)]
struct Prefix {
    a: [u8; MAX_PARITY],
    /// `α^(j (m-1-k))`.
    pw: [u8; MAX_PARITY],
    k: usize,
}

impl Prefix {
    fn start(p: usize, m: usize) -> Self {
        let mut pw = [0u8; MAX_PARITY];
        for (j, w) in pw.iter_mut().enumerate().take(p) {
            *w = alpha_pow(j * ((m + 254) % 255));
        }
        Prefix { a: [0; MAX_PARITY], pw, k: 0 }
    }

    /// `r_k α^(j (m-1-k))`: byte `k`'s share of syndrome `j`.
    fn term(&self, j: usize, rk: u8) -> u8 {
        mul(rk, self.pw[j])
    }

    fn advance(&mut self, r: Received<'_>, p: usize) {
        let rk = r.at(self.k);
        for j in 0..p {
            self.a[j] ^= mul(rk, self.pw[j]);
            self.pw[j] = mul(self.pw[j], alpha_pow(255 - j % 255));
        }
        self.k += 1;
    }
}

/// Finds the codeword of `n` bytes, `p` of them parity, that the received
/// word explains with the fewest edits; writes the payload at the start of
/// `work`.
/// Without `checked` (a block's segment) the word carries no CRC: only the
/// code judges it (and the block's code and CRC after).
pub(super) fn decode(
    r: Received<'_>,
    p: usize,
    n: usize,
    work: &mut [u8],
    checked: bool,
) -> Result<(usize, Damage), DeframeError> {
    let m = r.len();
    if m < 5 {
        return Err(DeframeError::Short);
    }
    // The syndromes of the received word (Horner: one product a byte and
    // syndrome; every frame pays this, the edits' tries only a damaged one),
    // and the factors by which a drop or a duplicate at a position shifts
    // the bytes before it.
    let (mut t, mut drop_f, mut dup_f) = ([0u8; MAX_PARITY], [0u8; MAX_PARITY], [0u8; MAX_PARITY]);
    for j in 0..p {
        let a = alpha_pow(j);
        t[j] = (0..m).fold(0, |acc, i| mul(acc, a) ^ r.at(i));
        drop_f[j] = 1 ^ a;
        dup_f[j] = 1 ^ alpha_pow(255 - j % 255);
    }
    let mut s = [0u8; MAX_PARITY];
    let mut found = Found { r, work, p, n, checked, best: None };
    match m as isize - n as isize {
        0 => {
            found.consider(Edit::None, &t[..p]);
            if found.best.is_none() && p >= 4 && n <= PAIR_MAX {
                pairs(r, p, &t, &mut found, PairKind::DropDup);
            }
        }
        -1 => {
            let mut pa = Prefix::start(p, m);
            for a in 0..=m {
                for j in 0..p {
                    s[j] = t[j] ^ mul(drop_f[j], pa.a[j]);
                }
                found.consider(Edit::Drop(a), &s[..p]);
                if found.done(a) {
                    break;
                }
                pa.advance(r, p);
            }
        }
        1 => {
            let mut pa = Prefix::start(p, m);
            for a in 0..m {
                let ra = r.at(a);
                for j in 0..p {
                    s[j] = t[j] ^ pa.term(j, ra) ^ mul(dup_f[j], pa.a[j]);
                }
                found.consider(Edit::Dup(a), &s[..p]);
                if found.done(a) {
                    break;
                }
                pa.advance(r, p);
            }
        }
        -2 if p >= 3 && n <= PAIR_MAX => pairs(r, p, &t, &mut found, PairKind::Drops),
        2 if p >= 2 && n <= PAIR_MAX => pairs(r, p, &t, &mut found, PairKind::Dups),
        d if d > 2 => {
            // A lost delimiter: this frame, then (some of) the next.
            let first = Received { bytes: r.bytes.get(..n).unwrap_or(&[]), h: r.h };
            return decode(first, p, n, found.work, checked);
        }
        _ => {}
    }
    found.finish().ok_or(DeframeError::Checksum)
}

/// The best explanation of a damaged frame found so far: the one that
/// passes the code and the CRC with the fewest corrections (an edit
/// guessed a few bytes off the true position also passes, with the bytes
/// between counted as substituted).
struct Found<'r, 'w> {
    r: Received<'r>,
    work: &'w mut [u8],
    p: usize,
    n: usize,
    /// Whether the word ends in a CRC-32 of its data.
    checked: bool,
    best: Option<(usize, Edit, rs::Corrections)>,
}

impl Found<'_, '_> {
    /// Tries the word `edit` makes, its syndromes `s`: kept when the code
    /// explains it (a guess keeping one parity equation spare), the CRC
    /// holds, and it needs fewer corrections than the best so far.
    fn consider(&mut self, edit: Edit, s: &[u8]) {
        let (p, n) = (self.p, self.n);
        let e = edit.inserted();
        let guessed = edit != Edit::None;
        if guessed && p < e + 1 {
            return;
        }
        let max_errors = match edit {
            Edit::None => p / 2,
            Edit::Drop(_) | Edit::Dup(_) => (p - e - 1) / 2,
            // Pairs: at most one error more on longer codewords (`pairs`).
            _ if n <= PAIR_FULL => (p - e - 1) / 2,
            _ => ((p - e - 1) / 2).min(1),
        };
        let erasures = edit.erasures();
        let Some(fixes) = rs::solve(s, n, &erasures[..e], max_errors) else { return };
        let errors = fixes.errors(&erasures[..e]);
        if self.best.is_some_and(|b| b.0 <= errors) {
            return;
        }
        if self.rebuild(edit, &fixes).is_some() {
            self.best = Some((errors, edit, fixes));
        }
    }

    /// Writes the word `edit` makes into `work`, corrected; the payload's
    /// length if its CRC holds.
    fn rebuild(&mut self, edit: Edit, fixes: &rs::Corrections) -> Option<usize> {
        let (p, n) = (self.p, self.n);
        if edit.apply(self.r, self.work) != n || !fixes.apply(self.work.get_mut(..n)?) {
            return None;
        }
        if !self.checked {
            return Some(n - p);
        }
        let k = n - p - 4;
        let (payload, rest) = self.work.get(..n - p)?.split_at(k);
        (crc32(payload).to_le_bytes() == [rest[0], rest[1], rest[2], rest[3]]).then_some(k)
    }

    /// Whether a scan at `position` is past where a better explanation
    /// than the best could be.
    fn done(&self, position: usize) -> bool {
        self.best.is_some_and(|(errors, edit, _)| errors == 0 || position > edit.position() + self.p / 2 + 1)
    }

    /// The best explanation, rebuilt at the start of `work`: the payload's
    /// length and the damage.
    fn finish(mut self) -> Option<(usize, Damage)> {
        let (errors, edit, fixes) = self.best?;
        let k = self.rebuild(edit, &fixes)?;
        Some((k, edit.damage(errors)))
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum PairKind {
    Drops,
    Dups,
    DropDup,
}

/// Tries every pair of edits of `kind`, explanations with no other
/// error only (a pair leaves few equations to spare, and the tries are
/// many). Each try first computes the syndromes the first Forney syndrome
/// needs (one more than the edits insert) from prefix sums kept for those
/// alone; only the one try in 256 whose first Forney syndrome vanishes gets
/// the rest, from prefix sums made afresh. So the scan costs a few field
/// operations per pair of positions, what a small chip can afford.
fn pairs(r: Received<'_>, p: usize, t: &[u8; MAX_PARITY], found: &mut Found<'_, '_>, kind: PairKind) {
    let m = r.len();
    let n = found.n;
    let e = match kind {
        PairKind::Drops => 2,
        PairKind::DropDup => 1,
        PairKind::Dups => 0,
    };
    // Short codewords (a bad line's) get the full search, any error the
    // parity allows besides the edits; longer ones the quick check first:
    // syndromes for three Forney syndromes (one error besides the edits)
    // where the parity allows it with one equation spare, else for one.
    let full = n <= PAIR_FULL;
    let w = if full {
        p
    } else if p >= e + 4 {
        e + 3
    } else {
        e + 1
    };
    if p < e + 1 {
        return;
    }
    let mut s = [0u8; MAX_PARITY];
    let mut pa = Prefix::start(w, m);
    let last = if kind == PairKind::Dups { m } else { m + 1 };
    for a in 0..last {
        let mut pb = pa;
        for b in a..last {
            let edits: [Option<Edit>; 2] = match kind {
                PairKind::Drops => [Some(Edit::Drops(a, b)), None],
                PairKind::Dups => [(b > a).then_some(Edit::Dups(a, b)), None],
                // Insert before a and remove b (b >= a), or remove a and
                // insert before b (b > a + 1).
                PairKind::DropDup => {
                    [(b < m && b > a).then_some(Edit::DropDup(a, b)), (b > a + 1).then_some(Edit::DropDup(b, a))]
                }
            };
            for edit in edits.into_iter().flatten() {
                pair_syndromes(r, edit, (&pa, &pb), t, &mut s[..w]);
                if full {
                    found.consider(edit, &s[..p]);
                    continue;
                }
                if !few_errors(&s[..w], n, edit) {
                    continue;
                }
                let (fa, fb) = (prefix_at(r, p, a), prefix_at(r, p, b));
                pair_syndromes(r, edit, (&fa, &fb), t, &mut s[..p]);
                found.consider(edit, &s[..p]);
            }
            if b < m {
                pb.advance(r, w);
            }
        }
        if found.done(a) {
            return;
        }
        if a < m {
            pa.advance(r, w);
        }
    }
}

/// The prefix sums of the first `p` syndromes at byte `k`.
fn prefix_at(r: Received<'_>, p: usize, k: usize) -> Prefix {
    let mut x = Prefix::start(p, r.len());
    for _ in 0..k.min(r.len()) {
        x.advance(r, p);
    }
    x
}

/// Syndromes `s` (as many as `s` holds) of the word a pair of edits makes,
/// from the prefix sums at its two positions.
fn pair_syndromes(r: Received<'_>, edit: Edit, (pa, pb): (&Prefix, &Prefix), t: &[u8; MAX_PARITY], s: &mut [u8]) {
    let (a, b) = (pa.k, pb.k);
    let (ra, rb) = (r.at(a), r.at(b));
    for (j, sj) in s.iter_mut().enumerate() {
        let (up, down) = (alpha_pow(j), alpha_pow(255 - j % 255));
        *sj = match edit {
            Edit::Drops(..) => t[j] ^ mul(pa.a[j], mul(up, up) ^ up) ^ mul(pb.a[j], up ^ 1),
            Edit::Dups(..) => {
                let a1 = pa.a[j] ^ pa.term(j, ra);
                let b1 = pb.a[j] ^ pb.term(j, rb);
                mul(mul(down, down), pa.a[j]) ^ mul(down, pb.a[j] ^ a1) ^ t[j] ^ b1
            }
            Edit::DropDup(x, _) if x == a => {
                let b1 = pb.a[j] ^ pb.term(j, rb);
                pa.a[j] ^ mul(down, pb.a[j] ^ pa.a[j]) ^ t[j] ^ b1
            }
            _ => {
                // Remove a, insert before b.
                let a1 = pa.a[j] ^ pa.term(j, ra);
                pa.a[j] ^ mul(up, pb.a[j] ^ a1) ^ t[j] ^ pb.a[j]
            }
        };
    }
}

/// Whether syndromes `s` of a word of `n` bytes (the edit's erasures plus
/// one or three) may be explained by the erasures and at most one error
/// (three Forney syndromes `T` with `T1^2 = T0 T2`: one error's, or none's)
/// or, given one more only, by the erasures alone (`T0 = 0`). One wrong try
/// in about 256 passes, to be solved in full.
fn few_errors(s: &[u8], n: usize, edit: Edit) -> bool {
    let x = |i: usize| alpha_pow((n + 254 - i % 255) % 255);
    let er = edit.erasures();
    let e = edit.inserted();
    let gamma: [u8; 3] = match e {
        0 => [1, 0, 0],
        1 => [1, x(er[0]), 0],
        _ => {
            let (x1, x2) = (x(er[0]), x(er[1]));
            [1, x1 ^ x2, mul(x1, x2)]
        }
    };
    let forney = |i: usize| (0..=e).fold(0u8, |acc, k| acc ^ mul(gamma[k], s.get(i + e - k).copied().unwrap_or(0)));
    if s.len() >= e + 3 {
        let (t0, t1, t2) = (forney(0), forney(1), forney(2));
        mul(t1, t1) == mul(t0, t2) && (t0 != 0 || t1 == 0)
    } else {
        forney(0) == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rng(state: &mut u64) -> u64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        *state
    }

    /// Feeds `bytes` to a fresh deframer; the payloads it yields (at most
    /// four) and the damage of the last.
    fn frames_of(bytes: &[u8]) -> (heapless::Vec<heapless::Vec<u8, 600>, 4>, Damage) {
        let mut d = Deframer::new();
        let mut got = heapless::Vec::new();
        let mut damage = Damage::default();
        for &b in bytes {
            if let Ok(Some(f)) = d.push_frame(b) {
                damage = f.damage;
                let _ = got.push(heapless::Vec::from_slice(f.payload).unwrap());
            }
        }
        (got, damage)
    }

    #[test]
    fn frames_round_trip_and_survive_noise_between_them() {
        let every: [u8; 512] = core::array::from_fn(|i| i as u8);
        let payloads: [&[u8]; 5] = [b"hello robot", &[0u8; 30], &every[..241], &every[..249], &every];
        for payload in payloads {
            for parity in [0, 2, 4, 8] {
                let mut out = [0u8; MAX_FRAME];
                let Ok(n) = encode_frame_parity(payload, parity, &mut out) else {
                    assert!(payload.len() > max_payload(parity));
                    continue;
                };
                // COBS may take fewer code bytes than the most it could need.
                assert!(n <= frame_len(payload.len(), parity) && n + 2 >= frame_len(payload.len(), parity));
                assert!(out[..n - 1].iter().all(|&b| b != 0) && out[n - 1] == 0);
                let mut line = [0u8; MAX_FRAME + 4];
                line[..4].copy_from_slice(&[0x55, 0x13, 0x00, 0x00]);
                line[4..4 + n].copy_from_slice(&out[..n]);
                let (got, damage) = frames_of(&line[..4 + n]);
                assert_eq!(got.len(), 1);
                assert_eq!(&got[0][..], payload);
                assert!(damage.is_none());
            }
        }
        let mut out = [0u8; MAX_FRAME];
        assert_eq!(encode_frame(&[0; MAX_PAYLOAD + 1], &mut out), Err(FrameError::TooLong));
        assert_eq!(encode_frame_parity(&[1; 10], 3, &mut out), Err(FrameError::Parity));
        assert_eq!(encode_frame_parity(&[1; 10], 34, &mut out), Err(FrameError::Parity));
        assert_eq!(encode_frame(&[1; 10], &mut out[..10]), Err(FrameError::Buffer));
    }

    #[test]
    fn one_substituted_dropped_or_duplicated_byte_anywhere_is_repaired() {
        let payloads: [&[u8]; 3] = [b"\x01\x00\x10\x00\x00robot map 42\x00", b"0123456789abcdefghij", &[0u8; 9]];
        for payload in payloads {
            for parity in [2, 4] {
                let mut out = [0u8; 64];
                let n = encode_frame_parity(payload, parity, &mut out).unwrap();
                let expect = |bytes: &[u8], what: &str, i: usize| {
                    let (got, _) = frames_of(bytes);
                    assert_eq!(got.len(), 1, "{what} at {i} (parity {parity}) not repaired");
                    assert_eq!(&got[0][..], payload, "{what} at {i} gave a different payload");
                };
                for i in 0..n - 1 {
                    for v in [1u8, 0x5A, 0xFF, out[i] ^ 0x80] {
                        let mut bad = out;
                        bad[i] = if v == 0 || v == out[i] { out[i] ^ 1 } else { v };
                        if bad[i] != 0 {
                            expect(&bad[..n], "a substitution", i);
                        }
                    }
                    let mut drop = [0u8; 64];
                    drop[..i].copy_from_slice(&out[..i]);
                    drop[i..n - 1].copy_from_slice(&out[i + 1..n]);
                    // The header's bytes too: it is read with the edit.
                    expect(&drop[..n - 1], "a drop", i);
                    let mut dup = [0u8; 65];
                    dup[..=i].copy_from_slice(&out[..=i]);
                    dup[i + 1..=n].copy_from_slice(&out[i..n]);
                    expect(&dup[..=n], "a duplicate", i);
                }
            }
        }
    }

    /// Applies `k` random substitutions, drops or duplicates (in the header
    /// at most one) to `frame`; the damaged bytes in `out`.
    fn damage(frame: &[u8], k: usize, st: &mut u64, out: &mut [u8; 400]) -> usize {
        let mut len = frame.len();
        out[..len].copy_from_slice(frame);
        for e in 0..k {
            let skip = if e == 0 { 0 } else { HEADER + 1 };
            let i = skip + (rng(st) % (len - 1 - skip) as u64) as usize;
            match rng(st) % 3 {
                0 => out[i] = 1 + (rng(st) % 255) as u8,
                1 => {
                    out.copy_within(i + 1..len, i);
                    len -= 1;
                }
                _ => {
                    out.copy_within(i..len, i + 1);
                    len += 1;
                }
            }
        }
        len
    }

    #[test]
    fn damage_within_the_code_is_repaired_and_beyond_it_never_misread() {
        let mut st = 0x1234_5678_9ABC_DEF0u64;
        let payload: [u8; 60] = core::array::from_fn(|i| (i as u8).wrapping_mul(29) ^ 0x5A);
        let (mut repaired, mut tried) = ([0usize; 5], [0usize; 5]);
        for trial in 0..6000 {
            let parity = [4, 8, 16][trial % 3];
            let k = trial / 3 % 5;
            let mut frame = [0u8; 120];
            let n = encode_frame_parity(&payload, parity, &mut frame).unwrap();
            let mut bad = [0u8; 400];
            let len = damage(&frame[..n], k, &mut st, &mut bad);
            let (got, _) = frames_of(&bad[..len]);
            for g in &got {
                assert_eq!(&g[..], &payload[..], "trial {trial}: a wrong payload");
            }
            tried[k] += 1;
            repaired[k] += got.len();
        }
        // Up to two errors of any kind: always (measured: three, 65%; four,
        // 38%).
        assert_eq!(repaired[..3], tried[..3], "{repaired:?} of {tried:?}");
        assert!(repaired[3] * 2 > tried[3], "{repaired:?} of {tried:?}");
    }

    #[test]
    fn random_bytes_never_make_a_frame() {
        let mut st = 7u64;
        let mut d = Deframer::new();
        let mut frames = 0;
        for _ in 0..200_000 {
            let b = rng(&mut st) as u8;
            // Zeros as often as between frames of 60 bytes.
            let b = if b < 4 { 0 } else { b };
            if let Ok(Some(_)) = d.push(b) {
                frames += 1;
            }
        }
        assert_eq!(frames, 0);
    }

    #[test]
    fn oversized_frames_are_skipped_to_the_next_delimiter() {
        let mut d = Deframer::new();
        let mut errors = 0;
        for _ in 0..MAX_FRAME + 10 {
            if d.push(0x33).is_err() {
                errors += 1;
            }
        }
        assert_eq!(errors, 1);
        assert_eq!(d.push(0), Ok(None));
        let mut out = [0u8; MAX_FRAME];
        let n = encode_frame(b"after", &mut out).unwrap();
        let mut got = None;
        for &b in &out[..n] {
            if let Ok(Some(p)) = d.push(b) {
                got = Some(p.len());
            }
        }
        assert_eq!(got, Some(5));
    }
}
