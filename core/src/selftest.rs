//! A fixed mapping, wire and matching case, run the same way on the chip
//! and on a host, whose figures must agree to the bit: the proof that the
//! robot computes what the laptop computes.
//!
//! Two robots see a procedural street corner (floor of road and sidewalk, a
//! building wall, a fence, poles, a parked car) from anchor frames 2.5 m and
//! 5 degrees apart; their maps are built at 0.5 m from deterministic
//! jittered points, robot B's map is passed through the wire encoding, and
//! A matches B from a prior 2.5 m and 10 degrees off. The caller provides
//! every buffer.

use crate::classes::Class;
use crate::geometry::{from_xyz_rpy, transform_point, Isometry3};
use crate::map::{InsertError, LocalMap, VoxelStorage};
use crate::matching::{MatchError, MatchResult, MatchSettings, Matcher, Pyramid, PyramidError, PyramidStorage, Role};
use crate::wire::codec::{map_digest, CodecModel, MapDecoder, MapEncoder, MIN_CHUNK};
use crate::wire::message::check_golden;

/// Voxel size of the self-test maps (m).
pub const RESOLUTION: f32 = 0.5;
/// Pyramid levels of the self-test.
pub const LEVELS: usize = 3;
/// Map capacity the self-test needs (voxels per map).
pub const MAP_VOXELS: usize = 2048;
/// Coarse pyramid entries the self-test needs per map (it uses about 620).
pub const PYRAMID_ENTRIES: usize = 1024;
/// Footprint words the self-test needs per map (the model's footprint
/// takes about 13,700; the received map, prepared as scene only, 700).
pub const FOOTPRINT_WORDS: usize = 16_384;

/// What the self-test computed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Report {
    /// Voxels of robot A's and robot B's maps.
    pub voxels: [u32; 2],
    /// Digests of both maps' encodings.
    pub digests: [u32; 2],
    /// Bytes of B's map on the wire.
    pub wire_bytes: u32,
    /// Whether B's map decoded to the same digest and the golden bytes of
    /// every link and feed message and of a map file matched.
    pub wire_ok: bool,
    /// The match.
    pub result: MatchResult,
    /// The ground truth `T_A_B`.
    pub truth: Isometry3<f32>,
}

impl Report {
    /// Bits of the estimated transform: translation x, y, z, then the
    /// quaternion i, j, k, w.
    pub fn transform_bits(&self) -> [u32; 7] {
        let t = self.result.transform.translation.vector;
        let q = self.result.transform.rotation.coords;
        [t.x, t.y, t.z, q.x, q.y, q.z, q.w].map(f32::to_bits)
    }
}

/// The report as `selftest key=value` lines, every number exact (floats as
/// bits): what the firmware prints and a host compares.
impl core::fmt::Display for Report {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let t = self.transform_bits();
        writeln!(f, "selftest voxels={},{}", self.voxels[0], self.voxels[1])?;
        writeln!(f, "selftest digests={:08x},{:08x}", self.digests[0], self.digests[1])?;
        writeln!(f, "selftest wire_bytes={} wire_ok={}", self.wire_bytes, self.wire_ok)?;
        writeln!(
            f,
            "selftest transform={:08x},{:08x},{:08x},{:08x},{:08x},{:08x},{:08x}",
            t[0], t[1], t[2], t[3], t[4], t[5], t[6]
        )?;
        write!(
            f,
            "selftest status={} iterations={} inliers={} overlap={:08x}",
            self.result.status.as_str(),
            self.result.iterations,
            self.result.inliers,
            self.result.overlap.to_bits()
        )
    }
}

/// Why the self-test could not run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SelfTestError {
    /// A map rejected a point or was too small.
    Map(InsertError),
    /// A pyramid did not fit.
    Pyramid(PyramidError),
    /// The matcher refused to run.
    Match(MatchError),
    /// A buffer is too small.
    Buffer,
}

/// Robot B's anchor in robot A's frame, `T_A_B`.
pub fn truth() -> Isometry3<f32> {
    from_xyz_rpy(2.5, 0.3, 0.0, 0.0, 0.0, 5.0f32.to_radians())
}

/// A small deterministic generator (xorshift), the same everywhere.
struct Jitter(u32);

impl Jitter {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 17;
        self.0 ^= self.0 << 5;
        (self.0 >> 8) as f32 / (1u32 << 24) as f32 - 0.5
    }
}

/// Fuses robot `robot`'s view of the street corner into `map` (cleared
/// first): the world points within its field of view, in its anchor frame.
pub fn build_map<S: VoxelStorage>(robot: u8, map: &mut LocalMap<S>) -> Result<(), InsertError> {
    map.clear();
    let world_to_robot = if robot == 0 { Isometry3::identity() } else { truth().inverse() };
    let mut jitter = Jitter(0x9E37_79B9 ^ (u32::from(robot) * 0x85EB_CA6B));
    // Both see the same stretch of street (hard view edges that differ
    // would pull a correlative search towards aligning the edges).
    let (x0, x1) = (-8.0f32, 9.0f32);
    let mut put = |p: [f32; 3], class: Class, j: &mut Jitter| -> Result<(), InsertError> {
        if p[0] < x0 || p[0] > x1 {
            return Ok(());
        }
        let q = [p[0] + 0.02 * j.next(), p[1] + 0.02 * j.next(), p[2] + 0.02 * j.next()];
        map.insert_point(transform_point(&world_to_robot, q), class).map(|_| ())
    };
    let step = 0.125f32;
    for i in 0..=(18.0 / step) as i32 {
        let x = -9.0 + i as f32 * step;
        for k in 0..=(12.0 / step) as i32 {
            let y = -6.0 + k as f32 * step;
            // Surfaces lie mid-cell, so jitter does not split them in two.
            put([x, y, 0.1], if y.abs() < 3.0 { Class::Road } else { Class::Sidewalk }, &mut jitter)?;
        }
        // The building wall has an alley between x = 0.6 and 2.4.
        if !(0.6..2.4).contains(&x) {
            for k in 0..=(4.0 / step) as i32 {
                put([x, 6.6, 0.1 + k as f32 * step], Class::Building, &mut jitter)?;
            }
        }
    }
    // A side wall, square to the street, seen by both robots.
    for k in 0..=(3.4 / step) as i32 {
        for h in 0..=(3.0 / step) as i32 {
            put([-3.4, 3.2 + k as f32 * step, 0.1 + h as f32 * step], Class::Building, &mut jitter)?;
        }
    }
    for k in 0..=(12.0 / step) as i32 {
        for h in 0..=(1.5 / step) as i32 {
            put([8.6, -6.0 + k as f32 * step, 0.1 + h as f32 * step], Class::Fence, &mut jitter)?;
        }
    }
    for (px, py) in [(-5.0f32, 3.6f32), (-0.5, -3.8), (4.0, 3.7), (7.0, -3.6)] {
        for h in 0..=(5.0 / step) as i32 {
            for a in 0..8 {
                let ang = a as f32 * core::f32::consts::FRAC_PI_4;
                let (s, c) = libm::sincosf(ang);
                put([px + 0.12 * c, py + 0.12 * s, h as f32 * step], Class::Pole, &mut jitter)?;
            }
        }
    }
    for i in 0..=(4.2 / step) as i32 {
        for k in 0..=(1.8 / step) as i32 {
            let (x, y) = (-3.0 + i as f32 * step, -2.9 + k as f32 * step);
            put([x, y, 1.4], Class::Car, &mut jitter)?;
            put([x, -2.9, 0.3 + k as f32 * step * 0.6], Class::Car, &mut jitter)?;
        }
    }
    Ok(())
}

/// Runs the whole case. `a` and `b` are maps of at least [`MAP_VOXELS`]
/// voxels at [`RESOLUTION`]; `received` receives B's map through the wire;
/// `scratch` holds one `u32` per voxel; `chunk` is the encoding buffer; the
/// pyramid storages hold extras for [`MAP_VOXELS`] voxels, [`PYRAMID_ENTRIES`] coarse entries and
/// [`FOOTPRINT_WORDS`] words. `on_match` runs right before and after the
/// match (e.g. to read an instruction counter).
#[allow(clippy::too_many_arguments)]
pub fn run<S: VoxelStorage, P: PyramidStorage>(
    a: &mut LocalMap<S>,
    b: &mut LocalMap<S>,
    received: &mut LocalMap<S>,
    scratch: &mut [u32],
    chunk: &mut [u8],
    storage_a: P,
    storage_b: P,
    mut on_match: impl FnMut(bool),
) -> Result<Report, SelfTestError> {
    build_map(0, a).map_err(SelfTestError::Map)?;
    build_map(1, b).map_err(SelfTestError::Map)?;
    if chunk.len() < MIN_CHUNK {
        return Err(SelfTestError::Buffer);
    }
    // Wire: encode B chunk by chunk, decode into `received`.
    let digest_a = map_digest(a, scratch).map_err(|_| SelfTestError::Buffer)?;
    let (mut sending, mut receiving) = (CodecModel::new(), CodecModel::new());
    let mut encoder = MapEncoder::new(&*b, scratch, &mut sending).map_err(|_| SelfTestError::Buffer)?;
    let digest_b = encoder.digest();
    received.clear();
    let mut decoder = MapDecoder::new(b.len(), &mut receiving);
    let mut wire_bytes = 0u32;
    loop {
        let n = encoder.next_chunk(&mut sending, chunk).map_err(|_| SelfTestError::Buffer)?;
        if n == 0 {
            break;
        }
        wire_bytes += n as u32;
        let part = chunk.get(..n).ok_or(SelfTestError::Buffer)?;
        decoder.decode_chunk(&mut receiving, part, received).map_err(|_| SelfTestError::Buffer)?;
    }
    let mut wire_ok = decoder.is_complete() && decoder.digest() == digest_b;
    // Every message type's golden bytes, as in the wire tests.
    wire_ok &= check_golden().is_ok() && crate::wire::feed::check_golden().is_ok();
    // Match B (as received) against A.
    let pa = Pyramid::build(a, LEVELS, 1.0, storage_a).map_err(SelfTestError::Pyramid)?;
    let pb = Pyramid::build_as(received, LEVELS, 1.0, Role::Scene, storage_b).map_err(SelfTestError::Pyramid)?;
    let prior = from_xyz_rpy(2.0, -1.5, 0.0, 0.0, 0.0, 10.0f32.to_radians()) * truth();
    on_match(true);
    let result = Matcher::new(MatchSettings::default()).align(&pa, &pb, &prior);
    on_match(false);
    let result = result.map_err(SelfTestError::Match)?;
    let voxels = [a.len() as u32, b.len() as u32];
    // The map file's golden bytes, written and read with the now free maps.
    drop((pa, pb));
    wire_ok &= crate::wire::mapfile::check_golden(a, b).is_ok();
    Ok(Report { voxels, digests: [digest_a, digest_b], wire_bytes, wire_ok, result, truth: truth() })
}
