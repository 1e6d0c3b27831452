//! Label noise as a segmentation network makes it, to measure matching on
//! labels that are not ground truth (`--label-noise`).
//!
//! `network[:S]` models a network's errors: each class has its own error
//! rate (small objects worst, road best), errors are spatially coherent
//! (every 1 m cell of a scan decides once, per class, whether its points of
//! that class are wrong, and what they become), each scan independently,
//! and a wrong label goes to a class the network confuses it with
//! (pole/trunk/traffic-sign, car/truck/other-vehicle, road/parking/sidewalk,
//! terrain/vegetation, building/fence, ...); on top, a small share of
//! points is wrong independently. `S` scales every rate (default 1: about
//! 15% of KITTI's points wrong). `iid:P` gives each point a uniformly
//! random other class with probability `P`.
//!
//! Everything is seeded (`--seed`) and keyed by the scan's frame number, so
//! the same scan gets the same errors in every run and map.

use crate::rng::Rng;
use crate::sources::kitti::Frame;
use cosem_core::classes::{Class, MovingObjects, NUM_CLASSES};
use std::str::FromStr;

/// A label noise model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LabelNoise {
    /// Ground-truth labels.
    None,
    /// Each point wrong with this probability, to a uniformly random class.
    Iid(f64),
    /// A network's errors, rates scaled by this severity.
    Network(f64),
}

impl FromStr for LabelNoise {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (name, arg) = match s.split_once(':') {
            Some((n, a)) => (n, Some(a)),
            None => (s, None),
        };
        let number = |default: Option<f64>, range: std::ops::RangeInclusive<f64>| -> Result<f64, String> {
            let v = match (arg, default) {
                (Some(a), _) => a.parse::<f64>().map_err(|_| format!("`{s}`: `{a}` is not a number"))?,
                (None, Some(d)) => d,
                (None, None) => return Err(format!("`{s}`: expected {name}:P")),
            };
            if v.is_finite() && range.contains(&v) {
                Ok(v)
            } else {
                Err(format!("`{s}`: {v} is outside {range:?}"))
            }
        };
        match name {
            "none" => Ok(LabelNoise::None),
            "iid" => Ok(LabelNoise::Iid(number(None, 0.0..=1.0)?)),
            "network" => Ok(LabelNoise::Network(number(Some(1.0), 0.0..=4.0)?)),
            _ => Err(format!("`{s}`: expected none, network[:SEVERITY] or iid:P")),
        }
    }
}

/// Per class (by index): a network's error rate, and the classes it errs to.
fn confusion(c: Class) -> (f64, &'static [Class]) {
    use Class::*;
    match c {
        Car => (0.08, &[Truck, OtherVehicle]),
        Bicycle => (0.45, &[Motorcycle, Bicyclist]),
        Motorcycle => (0.45, &[Bicycle, Motorcyclist]),
        Truck => (0.50, &[Car, OtherVehicle]),
        OtherVehicle => (0.50, &[Car, Truck]),
        Person => (0.35, &[Bicyclist, Pole]),
        Bicyclist => (0.40, &[Person, Bicycle]),
        Motorcyclist => (0.50, &[Bicyclist, Motorcycle]),
        Road => (0.05, &[Parking, Sidewalk]),
        Parking => (0.35, &[Road, Sidewalk]),
        Sidewalk => (0.15, &[Road, Parking, Terrain]),
        OtherGround => (0.50, &[Sidewalk, Terrain]),
        Building => (0.12, &[Fence, Vegetation]),
        Fence => (0.35, &[Building, Vegetation]),
        Vegetation => (0.10, &[Terrain, Trunk, Building]),
        Trunk => (0.40, &[Vegetation, Pole]),
        Terrain => (0.25, &[Vegetation, Sidewalk]),
        Pole => (0.35, &[Trunk, TrafficSign]),
        TrafficSign => (0.40, &[Pole]),
    }
}

/// Share of points wrong independently of their cell, at severity 1.
const POINT_RATE: f64 = 0.03;

/// A deterministic hash of a scan's cell, class and purpose.
fn hash(seed: u64, frame: usize, cell: [i64; 3], class: u8, purpose: u64) -> Rng {
    let mut h = seed ^ (frame as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    for v in cell {
        h = (h ^ v as u64).wrapping_mul(0x100_0000_01B3).rotate_left(17);
    }
    h ^= u64::from(class).wrapping_mul(0xD6E8_FEB8_6659_FD93) ^ purpose.wrapping_mul(0xA076_1D64_78BD_642F);
    let mut rng = Rng::new(h);
    rng.next_u64();
    rng
}

/// What corrupting labels did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NoiseStats {
    /// Labelled points seen.
    pub points: usize,
    /// Points whose class was changed.
    pub changed: usize,
}

impl NoiseStats {
    /// Fraction of points changed.
    pub fn rate(&self) -> f64 {
        self.changed as f64 / self.points.max(1) as f64
    }
}

/// Corrupts `frame`'s labels in place with `noise` (`seed` and the frame
/// number choose the errors). Points without a class stay as they are; the
/// instance bits of a label are kept.
pub fn corrupt(frame: &mut Frame, noise: LabelNoise, seed: u64) -> NoiseStats {
    let mut stats = NoiseStats::default();
    if noise == LabelNoise::None {
        return stats;
    }
    let mut point_rng = hash(seed, frame.index, [0; 3], 0, 1);
    for (p, label) in frame.points.iter().zip(frame.labels.iter_mut()) {
        let Some(class) = Class::from_semantic_kitti(*label, MovingObjects::AsStatic) else { continue };
        stats.points += 1;
        let wrong = match noise {
            LabelNoise::None => None,
            LabelNoise::Iid(q) => point_rng.chance(q).then(|| {
                let k = point_rng.below(NUM_CLASSES as u64 - 1) as u8;
                Class::from_index(if k >= class.index() { k + 1 } else { k })
            }),
            LabelNoise::Network(s) => {
                let (rate, targets) = confusion(class);
                let cell = p.map(|v| v.floor() as i64);
                let mut cell_rng = hash(seed, frame.index, cell, class.index(), 2);
                let in_cell = cell_rng.chance((rate * s).min(0.95));
                let alone = point_rng.chance((POINT_RATE * s).min(0.5));
                (in_cell || alone).then(|| {
                    let rng = if in_cell { &mut cell_rng } else { &mut point_rng };
                    targets.get(rng.below(targets.len() as u64) as usize).copied()
                })
            }
        }
        .flatten();
        if let Some(c) = wrong.filter(|c| *c != class) {
            *label = (*label & 0xFFFF_0000) | u32::from(c.semantic_kitti_id());
            stats.changed += 1;
        }
    }
    stats
}

/// Corrupts every frame; returns the totals.
pub fn corrupt_all(frames: &mut [Frame], noise: LabelNoise, seed: u64) -> NoiseStats {
    let mut total = NoiseStats::default();
    for f in frames {
        let s = corrupt(f, noise, seed);
        total.points += s.points;
        total.changed += s.changed;
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(n: usize) -> Frame {
        let mut points = Vec::new();
        let mut labels = Vec::new();
        for i in 0..n {
            let c = Class::from_index((i % NUM_CLASSES) as u8).unwrap();
            points.push([(i % 37) as f32 * 0.7, (i / 37 % 41) as f32 * 0.7, (i % 5) as f32]);
            labels.push(u32::from(c.semantic_kitti_id()) | 0x0003_0000);
        }
        Frame { index: 3, time: None, pose: Default::default(), points, ranges: vec![1.0; n], labels, evidence: None }
    }

    #[test]
    fn parses_models() {
        assert_eq!("network".parse(), Ok(LabelNoise::Network(1.0)));
        assert_eq!("network:1.5".parse(), Ok(LabelNoise::Network(1.5)));
        assert_eq!("iid:0.2".parse(), Ok(LabelNoise::Iid(0.2)));
        assert!("iid".parse::<LabelNoise>().is_err());
        assert!("iid:2".parse::<LabelNoise>().is_err());
        assert!("network:nan".parse::<LabelNoise>().is_err());
        assert!("gauss".parse::<LabelNoise>().is_err());
    }

    #[test]
    fn seeded_coherent_and_confusable() {
        let (mut a, mut b, mut c) = (frame(20_000), frame(20_000), frame(20_000));
        let sa = corrupt(&mut a, LabelNoise::Network(1.0), 7);
        corrupt(&mut b, LabelNoise::Network(1.0), 7);
        let sc = corrupt(&mut c, LabelNoise::Network(1.0), 8);
        assert_eq!(a.labels, b.labels, "same seed, same errors");
        assert_ne!(a.labels, c.labels, "another seed, other errors");
        assert!((0.1..0.4).contains(&sa.rate()) && sc.changed > 0, "{}", sa.rate());
        // Instance bits kept; every wrong class is one the network confuses.
        let orig = frame(20_000);
        for (o, n) in orig.labels.iter().zip(&a.labels) {
            assert_eq!(o >> 16, n >> 16);
            if o != n {
                let from = Class::from_semantic_kitti(*o, MovingObjects::AsStatic).unwrap();
                let to = Class::from_semantic_kitti(*n, MovingObjects::AsStatic).unwrap();
                assert!(confusion(from).1.contains(&to), "{from:?} -> {to:?}");
            }
        }
        let iid = corrupt(&mut frame(20_000), LabelNoise::Iid(0.2), 1);
        assert!((0.17..0.23).contains(&iid.rate()), "{}", iid.rate());
    }
}
