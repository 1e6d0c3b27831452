//! Compact label distributions fused by Bayes' rule.
//!
//! With the symmetric sensor model "the label is right with probability `p`,
//! otherwise any other class equally likely", the posterior over the true
//! class after observations `o_1..o_n` (uniform prior) is
//! `P(l) ∝ exp(n_l * e)`, where `n_l` counts observations of `l` and
//! `e = ln(p (C-1) / (1-p))` is the evidence of one observation. So a voxel
//! only needs, per class, the summed log-likelihood ratio against a class it
//! never saw: its *score*. Scores are kept for the top [`LABEL_SLOTS`] classes,
//! quantised to 1/8 nat in 11 bits, and packed with the class into one `u16`
//! per slot: 8 bytes per voxel.
//!
//! Beyond four classes the distribution is a weighted Misra–Gries summary,
//! which has a Bayes reading: untracked classes share one pooled score. An
//! observation of an untracked class raises that pool, i.e. lowers every
//! tracked score by its evidence; slots that reach the pool are freed, and the
//! class takes a freed slot with what is left of its evidence. With four or
//! fewer distinct classes the fusion is exact (up to the quantisation) and
//! independent of the order of the observations; with more, a class holding
//! more than 5/9 of the evidence is still the argmax whatever the order. A
//! score that would pass the 11-bit ceiling shifts all scores down instead,
//! which keeps the ratios between the tracked classes' probabilities.

use crate::classes::{Class, NUM_CLASSES};

/// Number of classes a voxel tracks.
pub const LABEL_SLOTS: usize = 4;
/// Score units per nat of evidence.
pub const SCORE_UNITS_PER_NAT: f32 = 8.0;
/// Largest score a slot holds (11 bits).
pub const SCORE_MAX: u16 = 0x07FF;
const CLASS_SHIFT: u32 = 11;

/// The Bayes sensor model for hard labels: a label is right with probability
/// `accuracy`, otherwise it is any other class with equal probability.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SensorModel {
    /// Probability that an observed label is the true class, in `(1/19, 1)`.
    pub accuracy: f32,
}

impl Default for SensorModel {
    /// 0.8: ground-truth labels are near perfect, network labels are not;
    /// this keeps a few wrong labels from flipping a well-observed voxel.
    fn default() -> Self {
        SensorModel { accuracy: 0.8 }
    }
}

impl SensorModel {
    /// Whether the accuracy is a usable probability: above chance, below 1.
    pub fn is_valid(&self) -> bool {
        self.accuracy.is_finite() && self.accuracy > 1.0 / NUM_CLASSES as f32 && self.accuracy < 1.0
    }

    /// Evidence of one observation, in score units (at least 1).
    pub fn evidence_units(&self) -> u16 {
        let p = self.accuracy;
        let nats = libm::logf(p * (NUM_CLASSES as f32 - 1.0) / (1.0 - p));
        let units = libm::roundf(nats * SCORE_UNITS_PER_NAT);
        if units.is_nan() || units < 1.0 {
            1
        } else if units >= SCORE_MAX as f32 {
            SCORE_MAX
        } else {
            units as u16
        }
    }
}

/// Why raw label slots were rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LabelError {
    /// A slot names a class index beyond the table.
    UnknownClass,
    /// Two slots name the same class.
    DuplicateClass,
    /// Slots are not in canonical order (score descending, then class).
    NotCanonical,
}

impl core::fmt::Display for LabelError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            LabelError::UnknownClass => "label slot names an unknown class",
            LabelError::DuplicateClass => "two label slots name the same class",
            LabelError::NotCanonical => "label slots are not in canonical order",
        })
    }
}

impl core::error::Error for LabelError {}

/// The top classes of a voxel with their scores, canonically ordered:
/// highest score first, ties by class index. Slot 0 holds the most probable
/// class.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(C)]
pub struct LabelDistribution {
    slots: [u16; LABEL_SLOTS],
}

fn slot_class(slot: u16) -> Option<Class> {
    let c = slot >> CLASS_SHIFT;
    if c == 0 {
        None
    } else {
        Class::from_index((c - 1) as u8)
    }
}

fn slot_score(slot: u16) -> u16 {
    slot & SCORE_MAX
}

fn make_slot(class: Class, score: u16) -> u16 {
    ((u16::from(class.index()) + 1) << CLASS_SHIFT) | score.min(SCORE_MAX)
}

/// Canonical order key: score descending, then class index ascending; empty last.
fn order_key(slot: u16) -> (u8, u16, u16) {
    if slot == 0 {
        (1, 0, 0)
    } else {
        (0, SCORE_MAX - slot_score(slot), slot >> CLASS_SHIFT)
    }
}

impl LabelDistribution {
    /// No observation yet.
    pub const EMPTY: LabelDistribution = LabelDistribution { slots: [0; LABEL_SLOTS] };

    /// Whether no class was observed.
    pub fn is_empty(&self) -> bool {
        self.slots[0] == 0
    }

    /// The packed slots, as stored (for encoders).
    pub fn raw(&self) -> [u16; LABEL_SLOTS] {
        self.slots
    }

    /// Rebuilds a distribution from packed slots, checking them.
    pub fn from_raw(slots: [u16; LABEL_SLOTS]) -> Result<Self, LabelError> {
        for (i, &s) in slots.iter().enumerate() {
            if s != 0 && slot_class(s).is_none() {
                return Err(LabelError::UnknownClass);
            }
            // A zero score would be indistinguishable from an untracked class.
            if s != 0 && slot_score(s) == 0 {
                return Err(LabelError::NotCanonical);
            }
            for &t in &slots[..i] {
                if s != 0 && (t >> CLASS_SHIFT) == (s >> CLASS_SHIFT) {
                    return Err(LabelError::DuplicateClass);
                }
            }
            if i > 0 && order_key(slots[i - 1]) > order_key(s) {
                return Err(LabelError::NotCanonical);
            }
        }
        Ok(LabelDistribution { slots })
    }

    /// Tracked classes with their scores (score units), most probable first.
    pub fn entries(&self) -> impl Iterator<Item = (Class, u16)> + '_ {
        self.slots.iter().filter_map(|&s| slot_class(s).map(|c| (c, slot_score(s))))
    }

    /// The most probable class (ties: the lower class index).
    pub fn argmax(&self) -> Option<Class> {
        slot_class(self.slots[0])
    }

    /// Adds `evidence` score units for `class` (Bayes' rule in log form).
    pub fn observe(&mut self, class: Class, evidence: u16) {
        let evidence = evidence.min(SCORE_MAX);
        if evidence == 0 {
            return;
        }
        let tag = (u16::from(class.index()) + 1) << CLASS_SHIFT;
        let tracked = self.slots.iter().position(|&s| s != 0 && (s & !SCORE_MAX) == tag);
        let (target, new_score) = match tracked {
            Some(i) => (i, u32::from(evidence) + u32::from(slot_score(self.slots[i]))),
            None => {
                if self.slots[LABEL_SLOTS - 1] != 0 {
                    // Full: raise the pooled baseline by what can be paid for.
                    let weakest = slot_score(self.slots[LABEL_SLOTS - 1]);
                    let paid = weakest.min(evidence);
                    self.lower_all(paid, LABEL_SLOTS);
                    if evidence <= paid {
                        self.canonicalise();
                        return;
                    }
                    let free = self.slots.iter().position(|&s| s == 0).unwrap_or(LABEL_SLOTS - 1);
                    (free, u32::from(evidence - paid))
                } else {
                    let free = self.slots.iter().position(|&s| s == 0).unwrap_or(LABEL_SLOTS - 1);
                    (free, u32::from(evidence))
                }
            }
        };
        let mut new_score = new_score;
        if new_score > u32::from(SCORE_MAX) {
            self.lower_all((new_score - u32::from(SCORE_MAX)) as u16, target);
            new_score = u32::from(SCORE_MAX);
        }
        if let Some(slot) = self.slots.get_mut(target) {
            *slot = make_slot(class, new_score as u16);
        }
        self.canonicalise();
    }

    /// Lowers every tracked score but slot `except` by `by`; frees slots
    /// that reach the baseline.
    fn lower_all(&mut self, by: u16, except: usize) {
        for (i, s) in self.slots.iter_mut().enumerate() {
            if i != except && *s != 0 {
                let left = slot_score(*s).saturating_sub(by);
                *s = if left == 0 { 0 } else { (*s & !SCORE_MAX) | left };
            }
        }
    }

    /// Fuses another distribution's evidence into this one (independent
    /// observations add their log-likelihood ratios).
    pub fn merge(&mut self, other: &LabelDistribution) {
        for (class, score) in other.entries() {
            self.observe(class, score);
        }
    }

    fn canonicalise(&mut self) {
        // Insertion sort of four elements.
        for i in 1..LABEL_SLOTS {
            let mut j = i;
            while j > 0 && order_key(self.slots[j - 1]) > order_key(self.slots[j]) {
                self.slots.swap(j - 1, j);
                j -= 1;
            }
        }
    }

    /// The full posterior over all classes. Untracked classes share the
    /// baseline score 0, so an empty distribution is uniform.
    pub fn probabilities(&self) -> [f32; NUM_CLASSES] {
        let top = f32::from(slot_score(self.slots[0])) / SCORE_UNITS_PER_NAT;
        let base = libm::expf(-top);
        let mut p = [base; NUM_CLASSES];
        for (class, score) in self.entries() {
            p[class.index() as usize] = libm::expf(f32::from(score) / SCORE_UNITS_PER_NAT - top);
        }
        let sum: f32 = p.iter().sum();
        for v in p.iter_mut() {
            *v /= sum;
        }
        p
    }

    /// Posterior probability of one class: [`Self::probabilities`]'s
    /// entry to the bit (the same terms summed in the same class order),
    /// without the full posterior's division of every class. Preparing a
    /// map and encoding an update ask it of every voxel.
    pub fn probability(&self, class: Class) -> f32 {
        let top = f32::from(slot_score(self.slots[0])) / SCORE_UNITS_PER_NAT;
        let base = libm::expf(-top);
        // The tracked classes' terms by class index (at most four).
        let mut tracked = [(u8::MAX, 0.0f32); LABEL_SLOTS];
        for (t, (c, score)) in tracked.iter_mut().zip(self.entries()) {
            *t = (c.index(), libm::expf(f32::from(score) / SCORE_UNITS_PER_NAT - top));
        }
        tracked.sort_unstable_by_key(|t| t.0);
        let (mut sum, mut next, mut own) = (0.0f32, 0, base);
        for i in 0..NUM_CLASSES as u8 {
            let term = match tracked.get(next) {
                Some(&(c, v)) if c == i => {
                    next += 1;
                    v
                }
                _ => base,
            };
            if i == class.index() {
                own = term;
            }
            sum += term;
        }
        own / sum
    }

    /// Probability that this voxel and `other` carry the same class,
    /// `sum_l p(l) q(l)`: the soft semantic weight of the matcher.
    pub fn same_class_probability(&self, other: &LabelDistribution) -> f32 {
        let p = self.probabilities();
        let q = other.probabilities();
        p.iter().zip(q.iter()).map(|(a, b)| a * b).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The one-class posterior is the full posterior's entry to the bit.
    #[test]
    fn probability_is_the_posteriors_entry_to_the_bit() {
        let mut next = crate::test_util::draws(0x2545_f491_4f6c_dd1du64);
        for _ in 0..20_000 {
            let mut d = LabelDistribution::default();
            for _ in 0..next(12) {
                let class = Class::from_index(next(NUM_CLASSES as u64) as u8).unwrap();
                d.observe(class, 1 + next(400) as u16);
            }
            let p = d.probabilities();
            for c in 0..NUM_CLASSES as u8 {
                let class = Class::from_index(c).unwrap();
                assert_eq!(d.probability(class).to_bits(), p[c as usize].to_bits(), "{d:?} {class:?}");
            }
        }
    }

    #[test]
    fn evidence_of_default_model() {
        // ln(0.8 * 18 / 0.2) = ln 72 = 4.277 nats = 34.2 units.
        assert_eq!(SensorModel::default().evidence_units(), 34);
        assert!(!SensorModel { accuracy: 1.0 }.is_valid());
        assert!(!SensorModel { accuracy: 0.05 }.is_valid());
        assert!(!SensorModel { accuracy: f32::NAN }.is_valid());
    }

    #[test]
    fn bayes_fusion_matches_counts() {
        let mut d = LabelDistribution::EMPTY;
        for _ in 0..3 {
            d.observe(Class::Road, 34);
        }
        d.observe(Class::Sidewalk, 34);
        assert_eq!(d.argmax(), Some(Class::Road));
        let p = d.probabilities();
        // exp(3e) / (exp(3e) + exp(e) + 17) with e = 34/8 nats.
        let e = 34.0f32 / 8.0;
        let z = (3.0 * e).exp() + e.exp() + 17.0;
        assert!((p[Class::Road.index() as usize] - (3.0 * e).exp() / z).abs() < 1e-5);
        assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        assert!(d.same_class_probability(&d) > 0.8);
    }

    #[test]
    fn saturation_keeps_differences() {
        let mut d = LabelDistribution::EMPTY;
        for _ in 0..100 {
            d.observe(Class::Building, 34);
        }
        for _ in 0..10 {
            d.observe(Class::Vegetation, 34);
        }
        let e: alloc_free::Vec4 = d.entries().collect();
        assert_eq!(e.0[0], Some((Class::Building, SCORE_MAX)));
        // Building saturated before vegetation was seen: vegetation sits far
        // below it, as in exact Bayes (where it would be 90 observations below).
        assert_eq!(d.argmax(), Some(Class::Building));
        assert!(d.probability(Class::Vegetation) < 1e-9);
        let mut d = LabelDistribution::EMPTY;
        for _ in 0..70 {
            d.observe(Class::Building, 34);
            d.observe(Class::Vegetation, 34);
        }
        d.observe(Class::Building, 34);
        let e: alloc_free::Vec4 = d.entries().collect();
        assert_eq!(e.0[0], Some((Class::Building, SCORE_MAX)));
        assert_eq!(e.0[1], Some((Class::Vegetation, SCORE_MAX - 34)));
    }

    #[test]
    fn fifth_class_raises_the_pooled_baseline() {
        let mut d = LabelDistribution::EMPTY;
        for (i, c) in [Class::Road, Class::Sidewalk, Class::Building, Class::Pole].iter().enumerate() {
            d.observe(*c, 10 * (i as u16 + 1));
        }
        // 5 units of trunk: every tracked class loses 5 against the pool.
        d.observe(Class::Trunk, 5);
        let e: alloc_free::Vec4 = d.entries().collect();
        assert_eq!(
            e.0,
            [Some((Class::Pole, 35)), Some((Class::Building, 25)), Some((Class::Sidewalk, 15)), Some((Class::Road, 5))]
        );
        // 11 more: road (5) reaches the pool and frees its slot, trunk keeps 6.
        d.observe(Class::Trunk, 11);
        let e: alloc_free::Vec4 = d.entries().collect();
        assert_eq!(
            e.0,
            [
                Some((Class::Pole, 30)),
                Some((Class::Building, 20)),
                Some((Class::Sidewalk, 10)),
                Some((Class::Trunk, 6))
            ]
        );
        assert_eq!(LabelDistribution::from_raw(d.raw()), Ok(d));
    }

    #[test]
    fn from_raw_rejects_bad_slots() {
        assert_eq!(LabelDistribution::from_raw([25 << 11 | 3, 0, 0, 0]), Err(LabelError::UnknownClass));
        assert_eq!(LabelDistribution::from_raw([1 << 11 | 3, 1 << 11 | 2, 0, 0]), Err(LabelError::DuplicateClass));
        assert_eq!(LabelDistribution::from_raw([1 << 11 | 3, 2 << 11 | 4, 0, 0]), Err(LabelError::NotCanonical));
        assert_eq!(LabelDistribution::from_raw([0, 2 << 11 | 4, 0, 0]), Err(LabelError::NotCanonical));
        assert_eq!(LabelDistribution::from_raw([1 << 11, 0, 0, 0]), Err(LabelError::NotCanonical));
    }

    /// A fixed array collector, so the tests need no allocator either.
    mod alloc_free {
        use crate::classes::Class;
        pub struct Vec4(pub [Option<(Class, u16)>; 4]);
        impl FromIterator<(Class, u16)> for Vec4 {
            fn from_iter<I: IntoIterator<Item = (Class, u16)>>(it: I) -> Self {
                let mut v = Vec4([None; 4]);
                for (i, e) in it.into_iter().take(4).enumerate() {
                    v.0[i] = Some(e);
                }
                v
            }
        }
    }
}
