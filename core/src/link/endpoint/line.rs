//! The line as the frames that arrive judge it: its damage rate, what
//! the deframer repairs, and the frame size that goes through best.

/// What the line does to frames, per byte: `rate` of any damage and
/// `repairable`, the part the deframer repairs when it is a frame's only
/// damage (a flipped bit, a duplicated byte). Both as `-ln(1 - p)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct LineModel {
    pub(super) rate: f32,
    pub(super) repairable: f32,
}

impl LineModel {
    /// The rate of damage that costs a frame of `len` bytes: `u` with
    /// `exp(-u len)` the chance that it arrives usable.
    pub(super) fn residual(&self, len: usize) -> f32 {
        let l = len.max(1) as f32;
        self.rate - libm::log1pf(self.repairable * l) / l
    }
}

/// The line, judged by the frames that arrive: a frame of `L` bytes
/// arrives whole with probability `exp(-tL)` and repaired with probability
/// `cL exp(-tL)`, so from the fractions of whole and repaired frames and
/// their mean length, `t = -ln(whole) / L` and `c = repaired / whole / L`.
/// Counts halve now and then, to follow a line that changes.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct LineEstimate {
    pub(super) good: u32,
    pub(super) repaired: u32,
    pub(super) bad: u32,
    pub(super) bytes: u32,
    /// Bytes of the frame being received.
    pub(super) current: u32,
}

impl LineEstimate {
    pub(super) fn byte(&mut self) {
        self.current = self.current.saturating_add(1);
    }

    pub(super) fn frame(&mut self, whole: bool, repaired: bool) {
        if repaired {
            self.repaired += 1;
        } else if whole {
            self.good += 1;
        } else {
            self.bad += 1;
        }
        self.bytes = self.bytes.saturating_add(core::mem::take(&mut self.current));
        if self.good + self.repaired + self.bad > 400 {
            self.good /= 2;
            self.repaired /= 2;
            self.bad /= 2;
            self.bytes /= 2;
        }
    }

    /// The estimate, with a prior of one error in 2000 bytes worth four
    /// whole frames of 100 bytes.
    pub(super) fn model(&self) -> LineModel {
        const PRIOR_FRAMES: f32 = 4.0;
        const PRIOR_RATE: f32 = 1.0 / 2000.0;
        let frames = (self.good + self.repaired + self.bad) as f32 + PRIOR_FRAMES;
        let whole = self.good as f32 + PRIOR_FRAMES * libm::expf(-PRIOR_RATE * 100.0);
        let mean = ((self.bytes as f32 + PRIOR_FRAMES * 100.0) / frames).max(1.0);
        let rate = (-libm::logf((whole / frames).max(0.01)) / mean).min(0.7);
        let repairable = (self.repaired as f32 / whole / mean).min(rate);
        LineModel { rate, repairable }
    }
}
