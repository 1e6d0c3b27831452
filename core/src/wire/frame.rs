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
    /// No payload before the CRC.
    Short,
    /// The CRC does not match.
    Checksum,
}

impl core::fmt::Display for DeframeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            DeframeError::Oversized => "frame longer than the largest allowed",
            DeframeError::Cobs => "broken COBS framing",
            DeframeError::Short => "frame without a payload before its checksum",
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

/// Longest frame on the line (encoded, no delimiter) that the deframer
/// tries to repair: the short frames of a noisy line.
pub const REPAIR_MAX: usize = 160;

/// Reassembles frames from a byte stream, one byte at a time.
///
/// A frame that fails its checksum is repaired when one error explains it:
/// one flipped bit (located from the CRC syndrome, or tried in the COBS code
/// bytes) or one duplicated byte (tried where two neighbours are equal).
/// Every candidate must pass the CRC-32; a frame of `L` bytes yields about
/// `8L` candidates, so a frame broken in some other way passes as a wrong
/// repair with probability about `8L / 2^32` (the link's map digest catches
/// that too). On a line that flips, drops and duplicates bytes alike, this
/// saves two frames in three of those hit by a single error.
pub struct Deframer {
    buf: [u8; MAX_FRAME],
    len: usize,
    /// Dropping bytes until the next delimiter (after an oversized frame).
    skipping: bool,
    /// The raw bytes of a short frame, kept for repair (COBS decodes in place).
    raw: [u8; REPAIR_MAX],
}

/// A frame the deframer completed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Arrived<'a> {
    /// The payload, its CRC checked.
    pub payload: &'a [u8],
    /// Whether one flipped bit or one duplicated byte was repaired.
    pub repaired: bool,
}

impl Default for Deframer {
    fn default() -> Self {
        Self::new()
    }
}

impl Deframer {
    /// An empty deframer.
    pub const fn new() -> Self {
        Deframer { buf: [0; MAX_FRAME], len: 0, skipping: false, raw: [0; REPAIR_MAX] }
    }

    /// Feeds one byte. `Ok(Some(payload))` when it completed a good frame
    /// (whole or repaired); `Err` when it completed a bad one; `Ok(None)`
    /// otherwise.
    pub fn push(&mut self, byte: u8) -> Result<Option<&[u8]>, DeframeError> {
        Ok(self.push_frame(byte)?.map(|f| f.payload))
    }

    /// As [`Deframer::push`], saying also whether the frame was repaired:
    /// what a sender sizing frames for the line wants to know.
    pub fn push_frame(&mut self, byte: u8) -> Result<Option<Arrived<'_>>, DeframeError> {
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
        let keep = len <= REPAIR_MAX;
        if keep {
            self.raw[..len].copy_from_slice(&self.buf[..len]);
        }
        let error = match check(&mut self.buf[..len]) {
            Ok(n) => return Ok(Some(Arrived { payload: &self.buf[..n], repaired: false })),
            Err(e) => e,
        };
        if !keep {
            return Err(error);
        }
        let n = self.repair(len).ok_or(error)?;
        Ok(Some(Arrived { payload: &self.buf[..n], repaired: true }))
    }

    /// Tries the one-error explanations of the `len` raw bytes kept;
    /// leaves the payload and CRC in `buf` and returns the payload length.
    fn repair(&mut self, len: usize) -> Option<usize> {
        let (raw, buf) = (&self.raw[..len], &mut self.buf);
        // One flipped bit in a data byte: COBS keeps its place, so the CRC
        // syndrome says which. The byte must stay non-zero both ways.
        buf[..len].copy_from_slice(raw);
        if let Ok(n) = cobs_decode_in_place(&mut buf[..len]) {
            if n > 4 {
                let (payload, field) = buf[..n].split_at(n - 4);
                let syndrome = crc32(payload) ^ u32::from_le_bytes([field[0], field[1], field[2], field[3]]);
                if let Some((j, bit)) = super::crc::locate_bit_flip(n - 4, syndrome) {
                    let b = buf[j];
                    if b != 0 && b ^ bit != 0 {
                        buf[j] = b ^ bit;
                        return Some(n - 4);
                    }
                }
            }
        }
        // One flipped bit in a COBS code byte: each code byte up to the
        // broken one is where the walk goes.
        let mut at = 0;
        while let Some(&code) = raw.get(at) {
            for bit in 0..8 {
                let flipped = code ^ (1 << bit);
                if flipped == 0 {
                    continue;
                }
                buf[..len].copy_from_slice(raw);
                buf[at] = flipped;
                if let Ok(n) = check(&mut buf[..len]) {
                    return Some(n);
                }
            }
            at += usize::from(code);
        }
        // One duplicated byte: only where two neighbours are equal.
        for i in 1..len {
            if raw[i] == raw[i - 1] {
                buf[..i].copy_from_slice(&raw[..i]);
                buf[i..len - 1].copy_from_slice(&raw[i + 1..]);
                if let Ok(n) = check(&mut buf[..len - 1]) {
                    return Some(n);
                }
            }
        }
        None
    }
}

/// COBS-decodes `buf` in place and checks the CRC; the payload length.
fn check(buf: &mut [u8]) -> Result<usize, DeframeError> {
    let n = cobs_decode_in_place(buf)?;
    // An empty payload is no message (and five 0x01 bytes would pass as one).
    if n <= 4 {
        return Err(DeframeError::Short);
    }
    let (payload, crc) = buf[..n].split_at(n - 4);
    if crc32(payload).to_le_bytes() != [crc[0], crc[1], crc[2], crc[3]] {
        return Err(DeframeError::Checksum);
    }
    Ok(n - 4)
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
        assert_eq!(encode_frame(&[0; MAX_PAYLOAD + 1], &mut out), Err(FrameError::TooLong));
    }

    /// Feeds `bytes` to a fresh deframer; every payload it yields.
    fn frames_of(bytes: &[u8]) -> ([[u8; 64]; 4], [usize; 4], usize) {
        let mut d = Deframer::new();
        let (mut got, mut lens, mut k) = ([[0u8; 64]; 4], [0usize; 4], 0);
        for &b in bytes {
            if let Ok(Some(p)) = d.push(b) {
                got[k][..p.len()].copy_from_slice(p);
                lens[k] = p.len();
                k += 1;
            }
        }
        (got, lens, k)
    }

    #[test]
    fn one_flip_or_one_duplicate_is_repaired_never_misread() {
        // Payloads with zeros (several COBS code bytes) and without.
        let payloads: [&[u8]; 3] = [b"\x01\x00\x10\x00\x00robot map 42\x00", b"0123456789abcdefghij", &[0u8; 9]];
        for payload in payloads {
            let mut out = [0u8; 64];
            let n = encode_frame(payload, &mut out).unwrap();
            let check = |bytes: &[u8], what: &str| {
                let (got, lens, k) = frames_of(bytes);
                for f in 0..k {
                    assert_eq!(&got[f][..lens[f]], payload, "{what} gave a different payload");
                }
                k
            };
            for i in 0..n - 1 {
                for bit in 0..8 {
                    let mut bad = out;
                    bad[i] ^= 1 << bit;
                    let k = check(&bad[..n], "a flip");
                    // Only a flip that makes a zero (splitting the frame) loses it.
                    assert!(k == 1 || bad[i] == 0, "flip at {i} bit {bit} not repaired");
                }
                let mut dup = [0u8; 65];
                dup[..=i].copy_from_slice(&out[..=i]);
                dup[i + 1..=n].copy_from_slice(&out[i..n]);
                assert_eq!(check(&dup[..=n], "a duplicate"), 1, "duplicate at {i} not repaired");
            }
        }
    }

    #[test]
    fn two_errors_never_give_a_wrong_payload() {
        let payload: [u8; 30] = core::array::from_fn(|i| (i as u8).wrapping_mul(29) ^ 0x5A);
        let mut out = [0u8; 64];
        let n = encode_frame(&payload, &mut out).unwrap();
        let mut state = 0x1234_5678_9ABC_DEF0u64;
        let mut next = |m: usize| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state % m as u64) as usize
        };
        let mut repaired = 0;
        for _ in 0..20_000 {
            // Two errors, each a flip, a drop or a duplicate.
            let mut bytes = [0u8; 70];
            bytes[..n].copy_from_slice(&out[..n]);
            let mut len = n;
            for _ in 0..2 {
                let i = next(len - 1);
                match next(3) {
                    0 => bytes[i] ^= 1 << next(8),
                    1 => {
                        bytes.copy_within(i + 1..len, i);
                        len -= 1;
                    }
                    _ => {
                        bytes.copy_within(i..len, i + 1);
                        len += 1;
                    }
                }
            }
            let (got, lens, k) = frames_of(&bytes[..len]);
            for f in 0..k {
                assert_eq!(&got[f][..lens[f]], &payload[..]);
                repaired += 1;
            }
        }
        // Two errors that cancel (a drop and a duplicate of the same byte)
        // or fall on the delimiter still make frames; most do not.
        assert!(repaired < 20_000 / 4, "{repaired}");
    }
}
