//! The line as the frames that arrive judge it: how often it substitutes
//! bytes and how often it drops or duplicates them, and the frame size and
//! parity that carry the most data per byte of line.

use crate::wire::block::{
    BlockShape, PieceOutcome, BLOCK_DATA, BLOCK_SPARE, DESCRIPTOR_FRAME, DESCRIPTOR_PARITY, MAX_SEGMENTS, MAX_SPARES,
};
use crate::wire::frame::{
    frame_len, max_payload, Arrived, Damage, DeframeError, DEFAULT_PARITY, HEADER, PAIR_FULL, PAIR_MAX,
};
use crate::wire::message::{DATA_HEADER, DATA_OVERHEAD};
use crate::wire::rs::MAX_PARITY;

/// What the line does, per byte: the probability of a substituted byte
/// and of a dropped or duplicated one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(in crate::link) struct LineModel {
    pub(in crate::link) substitution: f32,
    pub(in crate::link) indel: f32,
}

/// How data goes out: data bytes per frame (or block), parity bytes per
/// frame, the block's shape when data goes in blocks ([`crate::wire::block`]),
/// and the chance that one arrives usable.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(in crate::link) struct FrameShape {
    pub(in crate::link) chunk: usize,
    pub(in crate::link) parity: usize,
    pub(in crate::link) arrival: f32,
    pub(in crate::link) block: Option<BlockShape>,
    /// The line looks clean (fewer than 2 damaged bytes in 1000): a
    /// frame not acknowledged in time is late, not lost.
    pub(in crate::link) clean: bool,
}

impl FrameShape {
    /// Before anything arrived: the largest frames with the default parity.
    pub(in crate::link) fn initial(config: &super::LinkConfig) -> Self {
        let chunk = usize::from(config.max_chunk).min(max_payload(DEFAULT_PARITY) - DATA_HEADER);
        FrameShape { chunk, parity: DEFAULT_PARITY, arrival: 1.0, block: None, clean: true }
    }

    /// The best shape for `line` within the configured sizes: frames, or
    /// blocks of the largest size where they carry more (frames and blocks
    /// both weighed by their arrival: a lost one costs a wait besides its
    /// bytes. Weighing blocks so chose more spares: 5% in 1.9-2.0 s
    /// instead of 2.14 s, simulated; weighing frames so too kept 20% at
    /// 13-16 s, where otherwise frames were chosen: 24.6 s, one map of 40
    /// undelivered).
    pub(in crate::link) fn for_line(line: LineModel, config: &super::LinkConfig) -> Self {
        let shape = line.best_shape(usize::from(config.min_chunk), usize::from(config.max_chunk));
        let frames =
            FrameShape { arrival: line.arrival(shape), clean: line.substitution + line.indel < 0.002, ..shape };
        // Half duplex: frames only. A turn's answer comes when its last
        // frame is in, and a block's is 500 bytes, not a frame's few: the
        // turn timing was not made for it (measured: storms of resends).
        if config.half_duplex {
            return frames;
        }
        // A block's payload: the data message and its CRC-32.
        let chunk = usize::from(config.max_chunk).min(BLOCK_DATA - DATA_HEADER - 4);
        match line.best_block(chunk) {
            // Both weighed as blocks are: a lost one's wait counts.
            Some((block, goodput, arrival)) if goodput > line.goodput(frames) * frames.arrival => {
                FrameShape { chunk, arrival, block: Some(block), ..frames }
            }
            _ => frames,
        }
    }
}

/// `P(K <= k)` for `K` Poisson with mean `mean`.
fn poisson_cdf(mean: f32, k: isize) -> f32 {
    if k < 0 {
        return 0.0;
    }
    let (mut term, mut sum) = (libm::expf(-mean), 0.0);
    for i in 0..=k {
        sum += term;
        term *= mean / (i + 1) as f32;
    }
    sum.min(1.0)
}

impl LineModel {
    /// The chance that a frame of `chunk` data bytes and `parity` parity
    /// bytes arrives usable: at most one damaged byte in its header, and in its
    /// codeword a damage the deframer repairs (substitutions up to half the
    /// parity, one edit with one parity equation spent and one kept, two
    /// edits on short codewords with two or three spent).
    pub(in crate::link) fn arrival(&self, shape: FrameShape) -> f32 {
        let n = shape.chunk + DATA_OVERHEAD - HEADER - 1 + shape.parity;
        self.header() * self.codeword(n, shape.parity)
    }

    /// The chance that a header arrives readable: one damaged byte at most.
    fn header(&self) -> f32 {
        let h = HEADER as f32 * (self.substitution + self.indel);
        libm::expf(-h) * (1.0 + h)
    }

    /// The chance that the deframer repairs a codeword of `n` bytes, `parity`
    /// of them parity, and its delimiter (see [`LineModel::arrival`]).
    fn codeword(&self, n: usize, parity: usize) -> f32 {
        let t = (parity / 2) as isize;
        let body = (n + 1) as f32;
        let (s, d) = (self.substitution * body, self.indel * body);
        let e = libm::expf(-d);
        let mut p = e * poisson_cdf(s, t);
        if parity >= 2 {
            p += e * d * poisson_cdf(s, t - 1);
        }
        if parity >= 4 && n <= PAIR_MAX {
            // Beyond the full search's length, one error at most besides.
            let cap = if n <= PAIR_FULL { isize::MAX } else { 1 };
            let (t2, t1) = ((t - 2).min(cap), (t - 1).min(cap));
            p += e * d * d / 2.0 * (0.25 * poisson_cdf(s, t2) + 0.75 * poisson_cdf(s, t1));
        }
        p
    }

    /// Data per byte of line of frames of `shape`.
    fn goodput(&self, shape: FrameShape) -> f32 {
        let line = frame_len(shape.chunk + DATA_HEADER, shape.parity) as f32;
        shape.chunk as f32 / line * self.arrival(shape)
    }

    /// The block shape that carries `chunk` data bytes with the most data
    /// per byte of line (weighed once more by its arrival: a lost block
    /// costs a wait besides its bytes), that figure, and the chance a block
    /// arrives: when a descriptor copy does and at least its data segments'
    /// count of segments (binomial, the spares added one by one).
    pub(in crate::link) fn best_block(&self, chunk: usize) -> Option<(BlockShape, f32, f32)> {
        let payload = chunk + DATA_HEADER;
        let desc = self.header() * self.codeword(DESCRIPTOR_FRAME - HEADER - 1, DESCRIPTOR_PARITY);
        let desc = 1.0 - (1.0 - desc) * (1.0 - desc);
        let mut best: Option<(BlockShape, f32, f32)> = None;
        for l in (4..=48).step_by(2) {
            let k = (payload + 4).div_ceil(l);
            if k * l > BLOCK_DATA || k > MAX_SEGMENTS {
                continue;
            }
            for p in (2..=8).step_by(2) {
                let q = self.codeword(l + p, p);
                // P(at least k of n segments), n = k + r, and P(k - 1 of n).
                let mut tail = libm::powf(q, k as f32);
                let mut below = k as f32 * libm::powf(q, (k - 1) as f32) * (1.0 - q);
                let top = MAX_SPARES.min(BLOCK_SPARE / l).min(MAX_SEGMENTS - k);
                for r in 0..=top {
                    let shape = BlockShape { segment: l, parity: p, spares: r };
                    let arrival = tail * desc;
                    // A lost block costs its bytes and a wait for its resend
                    // (of 300 bytes, not a frame's few): weighed twice.
                    let g = chunk as f32 / shape.line_len(payload) as f32 * arrival * arrival;
                    if best.is_none_or(|b| g > b.1) {
                        best = Some((shape, g, arrival));
                    }
                    let n = (k + r) as f32;
                    tail += below * q;
                    below *= (n + 1.0) / (n + 2.0 - k as f32) * (1.0 - q);
                }
            }
        }
        best
    }

    /// The shape with the most data per byte of line, data between
    /// `min_chunk` and `max_chunk`: every even parity, each with sizes on a
    /// coarse grid refined around its best.
    pub(in crate::link) fn best_shape(&self, min_chunk: usize, max_chunk: usize) -> FrameShape {
        let mut best =
            (FrameShape { chunk: min_chunk, parity: DEFAULT_PARITY, arrival: 0.0, block: None, clean: false }, -1.0f32);
        for parity in (0..=MAX_PARITY).step_by(2) {
            let top = max_chunk.min(max_payload(parity) - DATA_HEADER);
            if top < min_chunk {
                break;
            }
            // Sizes on a grid of eighths, then the neighbours of the best.
            let span = top - min_chunk;
            let mut local = (min_chunk, -1.0f32);
            for k in 0..=8 {
                let chunk = min_chunk + span * k / 8;
                let g = self.goodput(FrameShape { chunk, parity, arrival: 0.0, block: None, clean: false });
                if g > local.1 {
                    local = (chunk, g);
                }
            }
            let step = (span / 8).max(1);
            let (lo, hi) = (local.0.saturating_sub(step).max(min_chunk), (local.0 + step).min(top));
            for chunk in (lo..=hi).step_by((step / 8).max(1)) {
                let g = self.goodput(FrameShape { chunk, parity, arrival: 0.0, block: None, clean: false });
                if g > local.1 {
                    local = (chunk, g);
                }
            }
            if local.1 > best.1 {
                best = (FrameShape { chunk: local.0, parity, arrival: 0.0, block: None, clean: false }, local.1);
            }
        }
        best.0
    }
}

/// The line, judged by the frames that arrive: the bytes of the frames
/// decoded and what the deframer repaired in them, and the frames lost.
/// A lost frame had more errors than its code repairs; it is counted with
/// the errors it had on average given that, at the rate estimated so far
/// (`E[K | K > t]`, `K` Poisson: what repaired frames alone would
/// underestimate, as the frames with the most damage are the ones lost).
/// Counts halve now and then, to follow a line that changes.
#[derive(Clone, Copy, Debug, Default)]
pub(in crate::link) struct LineEstimate {
    pub(in crate::link) frames: u32,
    pub(in crate::link) bytes: f32,
    pub(in crate::link) substituted: f32,
    pub(in crate::link) indels: f32,
    /// Errors attributed to lost frames.
    pub(in crate::link) lost_errors: f32,
    /// Bytes of the frame being received.
    pub(in crate::link) current: u32,
    /// Parity of the last frame decoded (what the peer is using).
    pub(in crate::link) parity: u8,
}

/// `E[K | K > t]` for `K` Poisson with mean `mean`.
fn mean_beyond(mean: f32, t: usize) -> f32 {
    let (mut term, mut below, mut weighted) = (libm::expf(-mean), 0.0f32, 0.0f32);
    for k in 0..=t {
        below += term;
        weighted += k as f32 * term;
        term *= mean / (k + 1) as f32;
    }
    let above = 1.0 - below;
    if above < 1e-4 {
        return (t + 1) as f32;
    }
    ((mean - weighted) / above).max((t + 1) as f32)
}

impl LineEstimate {
    pub(in crate::link) fn byte(&mut self) {
        self.current = self.current.saturating_add(1);
    }

    /// A frame arrived: with `damage` repaired, or (`None`) lost.
    pub(in crate::link) fn frame(&mut self, damage: Option<(Damage, u8)>) {
        let len = core::mem::take(&mut self.current) as f32 + 1.0;
        if let Some((_, parity)) = damage {
            self.parity = parity;
        }
        self.record(len, damage.map(|d| d.0), self.parity);
    }

    /// What one byte pushed into a [`crate::wire::block::BlockDeframer`]
    /// told of the line: the block's segments and descriptors it ended
    /// (`pieces`), then the frame it completed or refused (`pushed`; a
    /// block's payload tells nothing beyond its pieces). A refused frame
    /// whose header could not be read tells nothing either, unless
    /// `header_lost_is_a_frame` (half duplex: there it is a frame a
    /// collision garbled). Whether the estimate changed. The byte itself
    /// is counted before it is pushed ([`LineEstimate::byte`]).
    pub(in crate::link) fn judge(
        &mut self,
        pieces: &[PieceOutcome],
        pushed: &Result<Option<Arrived<'_>>, DeframeError>,
        header_lost_is_a_frame: bool,
    ) -> bool {
        for o in pieces {
            self.piece(o.bytes, o.damage, o.parity);
        }
        match pushed {
            Ok(Some(f)) => {
                if f.segments == 0 {
                    self.frame(Some((f.damage, f.parity)));
                }
                true
            }
            Ok(None) => !pieces.is_empty(),
            Err(DeframeError::Header) if !header_lost_is_a_frame => {
                self.skip();
                !pieces.is_empty()
            }
            Err(_) if pieces.is_empty() => {
                self.frame(None);
                true
            }
            Err(_) => true,
        }
    }

    /// Bytes that told nothing of the line (no header could be read).
    pub(in crate::link) fn skip(&mut self) {
        self.current = 0;
    }

    /// A block's segment or descriptor of `bytes` bytes, `parity` of them
    /// parity, arrived with `damage` repaired, or (`None`) lost.
    pub(in crate::link) fn piece(&mut self, bytes: u16, damage: Option<Damage>, parity: u8) {
        self.current = 0;
        self.record(f32::from(bytes), damage, parity);
    }

    fn record(&mut self, len: f32, damage: Option<Damage>, parity: u8) {
        match damage {
            Some(d) => {
                self.substituted += f32::from(d.substituted);
                self.indels += f32::from(d.dropped) + f32::from(d.duplicated);
            }
            None => {
                let m = self.model();
                let t = usize::from(parity / 2);
                self.lost_errors += mean_beyond((m.substitution + m.indel) * len, t);
            }
        }
        self.frames += 1;
        self.bytes += len;
        if self.frames > 400 {
            self.frames /= 2;
            self.bytes /= 2.0;
            self.substituted /= 2.0;
            self.indels /= 2.0;
            self.lost_errors /= 2.0;
        }
    }

    /// The estimate, with a prior of one error in 2000 bytes (a third
    /// substitutions) worth 100 bytes; errors of lost frames split as the
    /// repaired ones are.
    pub(in crate::link) fn model(&self) -> LineModel {
        const PRIOR_BYTES: f32 = 100.0;
        const PRIOR_RATE: f32 = 1.0 / 2000.0;
        let bytes = self.bytes + PRIOR_BYTES;
        let sub = self.substituted + PRIOR_BYTES * PRIOR_RATE / 3.0;
        let indel = self.indels + PRIOR_BYTES * PRIOR_RATE * 2.0 / 3.0;
        let share = sub / (sub + indel);
        LineModel {
            substitution: ((sub + self.lost_errors * share) / bytes).min(0.5),
            indel: ((indel + self.lost_errors * (1.0 - share)) / bytes).min(0.5),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clean_line_gets_long_frames_and_little_parity_a_bad_one_more() {
        let clean = LineModel { substitution: 0.0, indel: 0.0 };
        let s = clean.best_shape(8, 240);
        assert_eq!((s.chunk, s.parity), (240, 0));
        let mut last = s;
        for rate in [0.001f32, 0.01, 0.05, 0.1, 0.2] {
            let m = LineModel { substitution: rate / 3.0, indel: rate * 2.0 / 3.0 };
            let s = m.best_shape(8, 240);
            assert!(s.chunk <= last.chunk, "{rate}: {s:?} after {last:?}");
            // Up to 5% errors most frames arrive; beyond, short frames pay.
            assert!(m.arrival(s) > 0.5 || rate > 0.05, "{rate}: {s:?} arrives {}", m.arrival(s));
            assert!(m.goodput(s) > 0.05, "{rate}: {s:?}");
            last = s;
        }
    }

    #[test]
    fn blocks_where_bytes_go_missing_often_frames_elsewhere() {
        let config = super::super::LinkConfig::default();
        for (rate, blocks) in [(0.0f32, false), (0.001, false), (0.01, false), (0.05, true), (0.1, true), (0.2, true)] {
            let m = LineModel { substitution: rate / 3.0, indel: rate * 2.0 / 3.0 };
            let shape = FrameShape::for_line(m, &config);
            assert_eq!(shape.block.is_some(), blocks, "{rate}: {shape:?}");
            if let Some(b) = shape.block {
                let (_, goodput, arrival) = m.best_block(shape.chunk).unwrap();
                // More than the best frames carry (both weighed by their
                // arrival), and most blocks arrive up to 10% (at 20%, half:
                // 0.52).
                let frames = m.best_shape(8, 300);
                assert!(goodput > m.goodput(frames) * m.arrival(frames), "{rate}: {shape:?}");
                let least = if rate <= 0.1 { 0.8 } else { 0.4 };
                assert!(arrival > least && (arrival - shape.arrival).abs() < 1e-6, "{rate}: {b:?} arrives {arrival}");
                assert!(b.fits(shape.chunk + DATA_HEADER), "{rate}: {b:?}");
            }
        }
        // Substitutions alone: frames correct them at less cost.
        let m = LineModel { substitution: 0.05, indel: 0.0 };
        assert_eq!(FrameShape::for_line(m, &config).block, None);
        // Half duplex: frames (the turns are timed for them).
        let m = LineModel { substitution: 0.1 / 3.0, indel: 0.2 / 3.0 };
        let half = super::super::LinkConfig { half_duplex: true, ..config };
        assert_eq!(FrameShape::for_line(m, &half).block, None);
    }

    #[test]
    fn the_estimate_follows_what_was_repaired() {
        let mut e = LineEstimate::default();
        for i in 0..300 {
            for _ in 0..99 {
                e.byte();
            }
            let d = Damage { substituted: (i % 2) as u8, dropped: (i % 4 == 0) as u8, duplicated: 0 };
            e.frame(Some((d, 4)));
        }
        let m = e.model();
        assert!((m.substitution - 0.005).abs() < 0.001, "{m:?}");
        assert!((m.indel - 0.0025).abs() < 0.001, "{m:?}");
    }
}
