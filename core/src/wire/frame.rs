//! Framing: a frame is `COBS(payload ++ CRC-32(payload))` followed by a zero
//! byte. COBS removes every zero from the body, so a zero always ends a
//! frame and a receiver resynchronises on the next one after any line error;
//! the CRC rejects what the line corrupted.

use super::crc::crc32;

/// Largest payload of a frame (fits a small UART buffer with room to spare).
pub const MAX_PAYLOAD: usize = 512;
/// Largest encoded frame: payload, CRC, COBS overhead, delimiter.
pub const MAX_FRAME: usize = MAX_PAYLOAD + 4 + (MAX_PAYLOAD + 4) / 254 + 2;

/// Why a frame could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// The payload exceeds [`MAX_PAYLOAD`].
    TooLong,
    /// The output buffer is too small.
    Buffer,
}

/// Why bytes received did not make a frame. The decoder has already
/// resynchronised: feed it the next bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DeframeError {
    /// More bytes than the largest frame before a delimiter.
    Oversized,
    /// The COBS structure is broken.
    Cobs,
    /// Shorter than a CRC.
    Short,
    /// The CRC does not match.
    Checksum,
}

impl core::fmt::Display for DeframeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            DeframeError::Oversized => "frame longer than the largest allowed",
            DeframeError::Cobs => "broken COBS framing",
            DeframeError::Short => "frame shorter than its checksum",
            DeframeError::Checksum => "frame checksum mismatch",
        })
    }
}

impl core::error::Error for DeframeError {}

/// COBS-encodes `input` into `out`; returns the length (no delimiter).
pub fn cobs_encode(input: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    let mut code_at = 0;
    let mut at = 1;
    let mut code: u8 = 1;
    if out.is_empty() {
        return Err(FrameError::Buffer);
    }
    for &b in input {
        if b == 0 {
            *out.get_mut(code_at).ok_or(FrameError::Buffer)? = code;
            code_at = at;
            at += 1;
            code = 1;
        } else {
            *out.get_mut(at).ok_or(FrameError::Buffer)? = b;
            at += 1;
            code += 1;
            if code == 0xFF {
                *out.get_mut(code_at).ok_or(FrameError::Buffer)? = code;
                code_at = at;
                at += 1;
                code = 1;
            }
        }
    }
    *out.get_mut(code_at).ok_or(FrameError::Buffer)? = code;
    Ok(at)
}

/// Decodes COBS in place; returns the decoded length.
pub fn cobs_decode_in_place(buf: &mut [u8]) -> Result<usize, DeframeError> {
    let (mut read, mut write) = (0usize, 0usize);
    while read < buf.len() {
        let code = buf[read];
        if code == 0 {
            return Err(DeframeError::Cobs);
        }
        read += 1;
        for _ in 1..code {
            let b = *buf.get(read).ok_or(DeframeError::Cobs)?;
            if b == 0 {
                return Err(DeframeError::Cobs);
            }
            buf[write] = b;
            write += 1;
            read += 1;
        }
        if code != 0xFF && read < buf.len() {
            buf[write] = 0;
            write += 1;
        }
    }
    Ok(write)
}

/// Encodes a message with `encode` (which writes its payload into a buffer
/// of [`MAX_PAYLOAD`] bytes and returns the length), then frames it into
/// `out`: the one place where "encode, then frame" is written.
pub fn frame_with<E: From<FrameError>>(
    out: &mut [u8],
    encode: impl FnOnce(&mut [u8]) -> Result<usize, E>,
) -> Result<usize, E> {
    let mut payload = [0u8; MAX_PAYLOAD];
    let n = encode(&mut payload)?;
    Ok(encode_frame(payload.get(..n).ok_or(FrameError::TooLong)?, out)?)
}

/// Encodes one frame of `payload` into `out` (delimiter included).
pub fn encode_frame(payload: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    if payload.len() > MAX_PAYLOAD {
        return Err(FrameError::TooLong);
    }
    let mut raw = [0u8; MAX_PAYLOAD + 4];
    let n = payload.len();
    raw[..n].copy_from_slice(payload);
    raw[n..n + 4].copy_from_slice(&crc32(payload).to_le_bytes());
    let len = cobs_encode(&raw[..n + 4], out)?;
    *out.get_mut(len).ok_or(FrameError::Buffer)? = 0;
    Ok(len + 1)
}

/// Reassembles frames from a byte stream, one byte at a time.
pub struct Deframer {
    buf: [u8; MAX_FRAME],
    len: usize,
    /// Dropping bytes until the next delimiter (after an oversized frame).
    skipping: bool,
}

impl Default for Deframer {
    fn default() -> Self {
        Self::new()
    }
}

impl Deframer {
    /// An empty deframer.
    pub const fn new() -> Self {
        Deframer { buf: [0; MAX_FRAME], len: 0, skipping: false }
    }

    /// Feeds one byte. `Ok(Some(payload))` when it completed a good frame;
    /// `Err` when it completed a bad one; `Ok(None)` otherwise.
    pub fn push(&mut self, byte: u8) -> Result<Option<&[u8]>, DeframeError> {
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
            // The tail of an oversized frame, or an empty frame (idle line).
            return Ok(None);
        }
        let n = cobs_decode_in_place(&mut self.buf[..len])?;
        if n < 4 {
            return Err(DeframeError::Short);
        }
        let (payload, crc) = self.buf[..n].split_at(n - 4);
        if crc32(payload).to_le_bytes() != [crc[0], crc[1], crc[2], crc[3]] {
            return Err(DeframeError::Checksum);
        }
        Ok(Some(payload))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cobs_known_vectors() {
        // From the COBS paper / Wikipedia examples.
        let cases: [(&[u8], &[u8]); 4] = [
            (&[0x00], &[0x01, 0x01]),
            (&[0x00, 0x00], &[0x01, 0x01, 0x01]),
            (&[0x11, 0x22, 0x00, 0x33], &[0x03, 0x11, 0x22, 0x02, 0x33]),
            (&[0x11, 0x00, 0x00, 0x00], &[0x02, 0x11, 0x01, 0x01, 0x01]),
        ];
        for (input, expected) in cases {
            let mut out = [0u8; 16];
            let n = cobs_encode(input, &mut out).unwrap();
            assert_eq!(&out[..n], expected);
            let mut back = out;
            let m = cobs_decode_in_place(&mut back[..n]).unwrap();
            assert_eq!(&back[..m], input);
        }
        let long: [u8; 300] = core::array::from_fn(|i| (i % 255 + 1) as u8);
        let mut out = [0u8; 310];
        let n = cobs_encode(&long, &mut out).unwrap();
        assert!(out[..n].iter().all(|&b| b != 0));
        let m = cobs_decode_in_place(&mut out[..n]).unwrap();
        assert_eq!(&out[..m], &long[..]);
    }

    #[test]
    fn frames_survive_noise_between_them() {
        let mut out = [0u8; MAX_FRAME];
        let n = encode_frame(b"hello robot", &mut out).unwrap();
        let mut d = Deframer::new();
        // Garbage, an idle zero, then the frame.
        for b in [0x55u8, 0x13, 0x00, 0x00] {
            let _ = d.push(b);
        }
        let mut got = None;
        for &b in &out[..n] {
            if let Ok(Some(p)) = d.push(b) {
                got = Some(p.len());
            }
        }
        assert_eq!(got, Some(11));
        // A flipped bit is a checksum or COBS error, never a frame.
        for i in 0..n - 1 {
            let mut bad = out;
            bad[i] ^= 0x04;
            let mut d = Deframer::new();
            for &b in &bad[..n] {
                assert!(!matches!(d.push(b), Ok(Some(_))), "flip at {i} gave a frame");
            }
        }
        assert_eq!(encode_frame(&[0; MAX_PAYLOAD + 1], &mut out), Err(FrameError::TooLong));
    }
}
