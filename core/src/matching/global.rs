//! Prior-free alignment from semantic landmarks: correspondences between two
//! maps' [`Landmark`]s that agree in class, size and pairwise distances.
//!
//! Candidate pairs are landmarks of one class with similar extents (at most
//! [`MAX_CANDIDATES`], the most similar first). Two candidates are
//! consistent when they use different landmarks on both sides and the
//! distance between their model landmarks equals the distance between their
//! scene landmarks (horizontally and vertically, within a tolerance): a
//! rigid motion keeps distances. The largest set of mutually consistent
//! candidates (a maximum clique of the consistency graph, found greedily
//! from every vertex) gives a 4-DoF transform (yaw about z and a
//! translation: both anchor frames are level) by least squares. The answer
//! is unique when no clique of the candidates it does not explain comes
//! close to it in size.

use super::landmarks::{extract, Landmark, LandmarkError};
use super::search::{search_global, GlobalSearch, GlobalSearchOutcome, SearchWindow};
use super::{MatchError, MatchResult, MatchSettings, MatchStatus, Matcher, Method, Pyramid, PyramidStorage};
use crate::geometry::{Isometry3, Translation3, UnitQuaternion, Vector3};
use crate::map::{LocalMap, VoxelStorage};

/// Most candidate correspondences considered.
pub const MAX_CANDIDATES: usize = 256;
const WORDS: usize = MAX_CANDIDATES / 32;

/// Settings of the landmark alignment.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GlobalSettings {
    /// Largest difference between a model distance and the matching scene
    /// distance (m): centroids of partly seen objects move.
    pub distance_tolerance: f32,
    /// Largest difference of a landmark pair's extents, each axis (m).
    pub extent_tolerance: f32,
    /// Fewest agreeing correspondences for an answer.
    pub min_agreeing: u32,
    /// The best clique must be this many times larger than the best clique
    /// of the candidates it does not explain, to be unique.
    pub uniqueness_ratio: f32,
}

impl Default for GlobalSettings {
    fn default() -> Self {
        GlobalSettings { distance_tolerance: 0.6, extent_tolerance: 1.5, min_agreeing: 4, uniqueness_ratio: 1.5 }
    }
}

/// The landmark alignment's answer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlobalOutcome {
    /// `T_model_scene` (4-DoF).
    pub transform: Isometry3<f32>,
    /// Correspondences in the largest consistent set.
    pub agreeing: u32,
    /// The largest consistent set among the candidates the answer does not explain.
    pub runner_up: u32,
    /// Whether the answer stands out (see [`GlobalSettings::uniqueness_ratio`]).
    pub unique: bool,
    /// Candidate correspondences considered.
    pub candidates: u32,
}

type Bits = [u32; WORDS];

fn has(bits: &Bits, i: usize) -> bool {
    bits.get(i / 32).is_some_and(|w| w & (1 << (i % 32)) != 0)
}

fn set(bits: &mut Bits, i: usize) {
    if let Some(w) = bits.get_mut(i / 32) {
        *w |= 1 << (i % 32);
    }
}

fn count(bits: &Bits) -> u32 {
    bits.iter().map(|w| w.count_ones()).sum()
}

fn and(a: &Bits, b: &Bits) -> Bits {
    let mut out = [0u32; WORDS];
    for (o, (x, y)) in out.iter_mut().zip(a.iter().zip(b.iter())) {
        *o = x & y;
    }
    out
}

/// The largest clique found greedily from every vertex of `allowed`:
/// repeatedly add the candidate with most neighbours among those still
/// compatible. Returns the clique.
fn greedy_clique(adj: &[Bits], allowed: &Bits, n: usize) -> Bits {
    let mut best = [0u32; WORDS];
    let mut best_size = 0;
    for start in 0..n {
        if !has(allowed, start) {
            continue;
        }
        let mut clique = [0u32; WORDS];
        set(&mut clique, start);
        let Some(row) = adj.get(start) else { continue };
        let mut open = and(row, allowed);
        loop {
            let mut pick = None;
            let mut pick_degree = 0;
            for v in 0..n {
                if !has(&open, v) {
                    continue;
                }
                let Some(r) = adj.get(v) else { continue };
                let d = count(&and(r, &open)) + 1;
                if d > pick_degree {
                    pick_degree = d;
                    pick = Some(v);
                }
            }
            let Some(v) = pick else { break };
            set(&mut clique, v);
            let Some(r) = adj.get(v) else { break };
            open = and(&open, r);
        }
        let size = count(&clique);
        if size > best_size {
            best_size = size;
            best = clique;
        }
    }
    best
}

/// Least-squares yaw and translation taking the scene points onto the model points.
fn fit(pairs: impl Iterator<Item = ([f32; 3], [f32; 3])> + Clone) -> Option<Isometry3<f32>> {
    let mut n = 0.0f32;
    let (mut ca, mut cb) = ([0.0f32; 3], [0.0f32; 3]);
    for (a, b) in pairs.clone() {
        n += 1.0;
        for k in 0..3 {
            ca[k] += a[k];
            cb[k] += b[k];
        }
    }
    if n < 2.0 {
        return None;
    }
    for k in 0..3 {
        ca[k] /= n;
        cb[k] /= n;
    }
    let (mut s, mut c) = (0.0f32, 0.0f32);
    for (a, b) in pairs {
        let (ax, ay) = (a[0] - ca[0], a[1] - ca[1]);
        let (bx, by) = (b[0] - cb[0], b[1] - cb[1]);
        s += bx * ay - by * ax;
        c += bx * ax + by * ay;
    }
    if !(s.is_finite() && c.is_finite()) || (s == 0.0 && c == 0.0) {
        return None;
    }
    let yaw = libm::atan2f(s, c);
    let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
    let rb = rot * Vector3::new(cb[0], cb[1], cb[2]);
    let t = Translation3::new(ca[0] - rb.x, ca[1] - rb.y, ca[2] - rb.z);
    Some(Isometry3::from_parts(t, rot))
}

/// Aligns `scene` landmarks to `model` landmarks with no prior. `None` when
/// fewer than [`GlobalSettings::min_agreeing`] correspondences agree.
pub fn align_landmarks(model: &[Landmark], scene: &[Landmark], settings: &GlobalSettings) -> Option<GlobalOutcome> {
    // Candidates, the most similar in extent first: (dissimilarity, model, scene).
    let mut cands: heapless::Vec<(f32, u8, u8), MAX_CANDIDATES> = heapless::Vec::new();
    for (i, a) in model.iter().enumerate().take(256) {
        for (j, b) in scene.iter().enumerate().take(256) {
            if a.class != b.class {
                continue;
            }
            let d = (0..3).map(|k| (a.extent[k] - b.extent[k]).abs()).fold(0.0f32, f32::max);
            if d.is_nan() || d > settings.extent_tolerance {
                continue;
            }
            let at = cands.iter().position(|&(e, _, _)| e > d).unwrap_or(cands.len());
            if at < MAX_CANDIDATES {
                if cands.is_full() {
                    cands.pop();
                }
                let _ = cands.insert(at, (d, i as u8, j as u8));
            }
        }
    }
    let n = cands.len();
    let mut adj = [[0u32; WORDS]; MAX_CANDIDATES];
    let tol = settings.distance_tolerance;
    let dist = |p: [f32; 3], q: [f32; 3]| {
        let (dx, dy) = (p[0] - q[0], p[1] - q[1]);
        (libm::sqrtf(dx * dx + dy * dy), p[2] - q[2])
    };
    let point = |set: &[Landmark], i: u8| set.get(usize::from(i)).map(|l| l.centroid).unwrap_or([0.0; 3]);
    for u in 0..n {
        for v in (u + 1)..n {
            let (Some(&(_, a1, b1)), Some(&(_, a2, b2))) = (cands.get(u), cands.get(v)) else { continue };
            if a1 == a2 || b1 == b2 {
                continue;
            }
            let (ha, za) = dist(point(model, a1), point(model, a2));
            let (hb, zb) = dist(point(scene, b1), point(scene, b2));
            if (ha - hb).abs() <= tol && (za - zb).abs() <= tol {
                set(&mut adj[u], v);
                set(&mut adj[v], u);
            }
        }
    }
    let mut all = [0u32; WORDS];
    for v in 0..n {
        set(&mut all, v);
    }
    let best = greedy_clique(&adj, &all, n);
    let agreeing = count(&best);
    if agreeing < settings.min_agreeing.max(2) {
        return None;
    }
    let cands_ref = &cands;
    let pairs = (0..n).filter(move |&v| has(&best, v)).filter_map(move |v| {
        let &(_, a, b) = cands_ref.get(v)?;
        Some((point(model, a), point(scene, b)))
    });
    let transform = fit(pairs)?;
    // The runner-up: the best clique among candidates this transform does not explain.
    let mut unexplained = [0u32; WORDS];
    for (v, &(_, a, b)) in cands.iter().enumerate() {
        let p = transform * nalgebra::Point3::from(point(scene, b));
        let q = point(model, a);
        let d = [p.x - q[0], p.y - q[1], p.z - q[2]];
        let r = libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        if r > 2.0 * tol {
            set(&mut unexplained, v);
        }
    }
    let runner_up = count(&greedy_clique(&adj, &unexplained, n));
    Some(GlobalOutcome {
        transform,
        agreeing,
        runner_up,
        unique: agreeing as f32 >= settings.uniqueness_ratio * runner_up as f32,
        candidates: n as u32,
    })
}

/// What the landmark stage found in two maps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Located {
    /// Landmarks of the model map and of the scene map.
    pub landmarks: [u32; 2],
    /// The landmark alignment, if enough landmarks agreed.
    pub outcome: Option<GlobalOutcome>,
}

/// Extracts both maps' landmarks and aligns them with no prior. `scratch`
/// holds one `u32` per voxel of the larger map (see [`extract`]); the
/// landmarks live only in this call's frame (about 8 KiB, plus about 12 KiB
/// for the correspondence graph), so a caller on a small stack gets that
/// memory back before it matches.
#[inline(never)]
pub fn locate<A: VoxelStorage, B: VoxelStorage>(
    model: &LocalMap<A>,
    scene: &LocalMap<B>,
    scratch: &mut [u32],
    settings: &GlobalSettings,
) -> Result<Located, LandmarkError> {
    let mut lm = heapless::Vec::new();
    let mut ls = heapless::Vec::new();
    extract(model, scratch, &mut lm)?;
    extract(scene, scratch, &mut ls)?;
    Ok(Located { landmarks: [lm.len() as u32, ls.len() as u32], outcome: align_landmarks(&lm, &ls, settings) })
}

/// Refines a landmark alignment with the matcher: from its transform when
/// it is unique, else `NoOverlap` at the identity, never a guess.
pub fn refine<A: PyramidStorage, B: PyramidStorage>(
    matcher: &Matcher,
    model: &Pyramid<'_, A>,
    scene: &Pyramid<'_, B>,
    outcome: Option<&GlobalOutcome>,
) -> Result<MatchResult, MatchError> {
    match outcome {
        Some(o) if o.unique => matcher.align(model, scene, &o.transform),
        _ => Ok(MatchResult::no_overlap()),
    }
}

/// Aligns two prepared maps with no prior from their landmarks (already
/// extracted): [`align_landmarks`], then [`refine`]. The landmark outcome,
/// if any, comes back too.
pub fn align_without_prior<A: PyramidStorage, B: PyramidStorage>(
    matcher: &Matcher,
    model: &Pyramid<'_, A>,
    scene: &Pyramid<'_, B>,
    landmarks: (&[Landmark], &[Landmark]),
    settings: &GlobalSettings,
) -> Result<(MatchResult, Option<GlobalOutcome>), MatchError> {
    let outcome = align_landmarks(landmarks.0, landmarks.1, settings);
    Ok((refine(matcher, model, scene, outcome.as_ref())?, outcome))
}

/// What the prior-free alignment tried.
#[derive(Clone, Debug, PartialEq)]
pub struct Searched {
    /// The coarse search's candidates and effort.
    pub search: GlobalSearchOutcome,
    /// The candidate whose refinement is the answer (the first that passed
    /// the verdict, else the best).
    pub chosen: usize,
    /// Candidates refined.
    pub refined: usize,
}

impl From<&Searched> for crate::wire::feed::GlobalReport {
    fn from(s: &Searched) -> Self {
        let (score, runner_up) = s.search.scores();
        crate::wire::feed::GlobalReport {
            score,
            runner_up,
            refined: s.refined.min(255) as u8,
            chosen: s.chosen.min(255) as u8,
            evaluations: s.search.evaluations,
        }
    }
}

/// Aligns two prepared maps with no prior: the coarse search over every
/// heading and offset ([`search_global`]) gives a few distinct candidates,
/// best first; each is refined by the matcher (a narrow search window
/// around it, then EM) until one passes the matcher's verdict
/// (`Converged`). None passing: the best candidate's result, whatever its
/// status. `None` with `NoOverlap` when a map has no footprint or the scene
/// no occupied cell. `searched` runs after the first search (e.g. to read
/// an instruction counter).
pub fn align_searched<A: PyramidStorage, B: PyramidStorage>(
    matcher: &Matcher,
    model: &Pyramid<'_, A>,
    scene: &Pyramid<'_, B>,
    settings: &GlobalSearch,
    mut searched: impl FnMut(),
) -> Result<(MatchResult, Option<Searched>), MatchError> {
    let semantic = matcher.settings.method != Method::Geometric;
    let (Some(fm), Some(fs)) = (model.footprint(), scene.footprint()) else {
        return Ok((MatchResult::no_overlap(), None));
    };
    // Candidates are exact on the search's lattice: a window of a few cells
    // and degrees around each holds its error.
    let deg = core::f32::consts::PI / 180.0;
    let window = SearchWindow { translation: 4.0, yaw: (2.0 * settings.yaw_step).max(6.0 * deg) };
    let local = Matcher::new(MatchSettings { search: Some(window), ..matcher.settings });
    // The best placement alone first (the cheap search); only when its
    // refinement fails, the few best distinct ones.
    let one = GlobalSearch { candidates: 1, ..*settings };
    let Some(search) = search_global(fm, fs, &one, semantic) else { return Ok((MatchResult::no_overlap(), None)) };
    searched();
    let Some(best) = search.candidates.first() else { return Ok((MatchResult::no_overlap(), None)) };
    let first = local.align(model, scene, &best.transform)?;
    if first.status == MatchStatus::Converged || settings.candidates <= 1 {
        return Ok((first, Some(Searched { search, chosen: 0, refined: 1 })));
    }
    let Some(more) = search_global(fm, fs, settings, semantic) else {
        return Ok((first, Some(Searched { search, chosen: 0, refined: 1 })));
    };
    for (k, c) in more.candidates.iter().enumerate().skip(1) {
        let r = local.align(model, scene, &c.transform)?;
        if r.status == MatchStatus::Converged {
            return Ok((r, Some(Searched { search: more.clone(), chosen: k, refined: k + 1 })));
        }
    }
    let refined = more.candidates.len().max(1);
    Ok((first, Some(Searched { search: more, chosen: 0, refined })))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classes::Class;
    use crate::geometry::{from_xyz_rpy, transform_point};

    fn lm(class: Class, p: [f32; 3]) -> Landmark {
        Landmark { class, centroid: p, extent: [0.3, 0.3, 3.0], voxels: 10 }
    }

    #[test]
    fn finds_a_turned_and_shifted_set_of_poles() {
        let model: std::vec::Vec<Landmark> =
            [[0.0, 0.0, 1.0], [7.0, 1.0, 1.2], [15.0, -2.0, 0.9], [3.0, 9.0, 1.1], [-6.0, 4.0, 1.0], [11.0, 12.0, 1.3]]
                .iter()
                .map(|p| lm(Class::Pole, *p))
                .collect();
        // The scene sees five of them from a frame turned by 150 degrees, 20 m away, plus two clutter poles.
        let t = from_xyz_rpy(20.0, -5.0, 0.3, 0.0, 0.0, 150f32.to_radians());
        let inv = t.inverse();
        let mut scene: std::vec::Vec<Landmark> =
            model[..5].iter().map(|l| lm(Class::Pole, transform_point(&inv, l.centroid))).collect();
        scene.push(lm(Class::Pole, [30.0, 30.0, 1.0]));
        scene.push(lm(Class::Pole, [-30.0, 2.0, 1.0]));
        let out = align_landmarks(&model, &scene, &GlobalSettings::default()).unwrap();
        assert_eq!(out.agreeing, 5);
        assert!(out.unique, "{out:?}");
        let d = out.transform * t.inverse();
        assert!(d.translation.vector.norm() < 1e-3 && d.rotation.angle() < 1e-4, "{out:?}");
        // Unrelated sets do not align.
        let far: std::vec::Vec<Landmark> =
            [[0.0, 0.0, 1.0], [1.0, 30.0, 1.0], [50.0, 3.0, 1.0]].iter().map(|p| lm(Class::Pole, *p)).collect();
        assert!(align_landmarks(&model, &far, &GlobalSettings::default()).is_none());
    }
}
