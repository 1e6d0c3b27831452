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
use super::rs::{self, MAX_PARITY};

mod deframe;
mod repair;
#[cfg(test)]
mod tests;

pub(super) use deframe::{reads_whole, Completed};
pub use deframe::{Arrived, Damage, Deframer};

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
