//! The pair robot's whole pipeline on this host with a board's capacities:
//! what a board of that size would report, before any firmware is written
//! (issue 31's sizing study). The core's robots over a clean simulated
//! 115200-baud line (`cosem_core::sim`), on kitti00 0:5 / 5:10 (a prior and
//! none), kitti08-loop 720 / 1500, kitti00-loop 88 / 850 (no overlap) and
//! 52 / 4501, with ground-truth and a network's labels.
//!
//!     cargo run --release --example board_capacity -- VOXELS COARSE MODEL_WORDS SCENE_WORDS VOXEL_M CROP_M [LEVELS SPARE_WORDS SEARCH_WORDS EM_ITERATIONS]
//!
//! Data from `$COSEM_DATA` (default `../shared/data`).
use cosem_core::map::{SceneMap, ScenePoint};
use cosem_core::robot::{Capacity, Robot, RobotConfig};
use cosem_core::sim::{self, SimRobot, Wire};
use cosem_core::wire::feed::RobotReport;
use cosem_host::boards::feeds::feeds;
use std::path::Path;

/// The capacity, voxel size and crop the arguments name.
fn capacity() -> (Capacity, f32, f32) {
    let args: Vec<String> = std::env::args().collect();
    let num = |i: usize, default: f64| args.get(i).and_then(|a| a.parse::<f64>().ok()).unwrap_or(default);
    let (v, e, mw, sw) =
        (num(1, 8192.0) as usize, num(2, 3840.0) as usize, num(3, 9216.0) as usize, num(4, 6656.0) as usize);
    let (levels, spare_words, search_words) = (num(7, 3.0) as usize, num(8, 0.0) as usize, num(9, 0.0) as usize);
    let em_iterations = num(10, 40.0) as u32;
    let cap = Capacity {
        voxels: v,
        coarse: e,
        model_words: mw,
        scene_words: sw,
        levels,
        spare_words,
        search_words,
        em_iterations,
    };
    (cap, num(5, 0.5) as f32, num(6, 25.0) as f32)
}

fn main() {
    let (cap, voxel, crop) = capacity();
    println!(
        "capacity {cap:?}: own region {} B, turn region {} B, received map {} B; {voxel} m voxels within {crop} m",
        cap.own_words() * 4,
        cap.turn_words() * 4,
        cap.voxels * core::mem::size_of::<ScenePoint>()
    );
    let root = std::env::var_os("COSEM_DATA").unwrap_or_else(|| "../shared/data".into());
    let data = Path::new(&root);
    if !data.join("kitti00").is_dir() {
        eprintln!("no kitti00 in {}: set COSEM_DATA", data.display());
        return;
    }
    let cases: &[(&str, &str, &str, bool, &str)] = &[
        ("kitti00", "0:5", "5:10", false, "none"),
        ("kitti00", "0:5", "5:10", true, "none"),
        ("kitti00", "0:5", "5:10", true, "network"),
        ("kitti08-loop", "720:721", "1500:1501", true, "none"),
        ("kitti08-loop", "720:721", "1500:1501", true, "network"),
        ("kitti00-loop", "88:89", "850:851", true, "none"),
        ("kitti00-loop", "88:89", "850:851", true, "network"),
        ("kitti00-loop", "52:53", "4501:4502", true, "none"),
    ];
    for &(seq, a, b, noprior, noise) in cases {
        let src = cosem_host::sources::source::Source::open(&data.join(seq), &Default::default()).unwrap();
        let ra: cosem_host::sources::kitti::FrameRange = a.parse().unwrap();
        let rb: cosem_host::sources::kitti::FrameRange = b.parse().unwrap();
        let gt = src.relative_pose(ra.start, rb.start).unwrap();
        let prior = if noprior { None } else { Some(cosem_host::boards::robots::default_prior(&gt)) };
        let noise: cosem_host::maps::noise::LabelNoise = noise.parse().unwrap();
        let f = feeds(&src, [ra, rb], voxel, crop, prior.as_ref(), 30_000, noise, 4).unwrap();
        let bytes = [f[0].bytes().unwrap(), f[1].bytes().unwrap()];
        let mut own = [vec![0u32; cap.own_words()], vec![0u32; cap.own_words()]];
        let mut turn = [vec![0u32; cap.turn_words()], vec![0u32; cap.turn_words()]];
        let mut pts = [vec![ScenePoint::EMPTY; cap.voxels], vec![ScenePoint::EMPTY; cap.voxels]];
        let [p0, p1] = &mut pts;
        let mut r0 = SceneMap::new(&mut p0[..], voxel).unwrap();
        let mut r1 = SceneMap::new(&mut p1[..], voxel).unwrap();
        let [o0, o1] = &mut own;
        let [t0, t1] = &mut turn;
        let mut a0 = Robot::new(RobotConfig::default(), o0, t0, cap, &mut r0).unwrap();
        let mut a1 = Robot::new(RobotConfig::default(), o1, t1, cap, &mut r1).unwrap();
        let out = sim::run(
            &mut [&mut a0 as &mut SimRobot<'_, '_, RobotReport>, &mut a1],
            &[&bytes[0], &bytes[1]],
            &[Wire::clean(0, 1, 115_200, 1)],
            3_600_000,
        );
        for (i, o) in out.iter().enumerate() {
            match o.result {
                Some(Ok(r)) => {
                    let t = r.result.transform().cast::<f64>();
                    let truth = if i == 0 { gt } else { gt.inverse() };
                    let d = t * truth.inverse();
                    println!(
                        "{seq} {a}/{b} noprior={noprior} {noise:?} robot {i}: status {} e_t {:.3} e_r {:.3} voxels {} nodes {:?}",
                        r.result.status,
                        d.translation.vector.norm(),
                        d.rotation.angle().to_degrees(),
                        r.map_voxels,
                        r.global.map(|g| g.evaluations)
                    );
                }
                Some(Err(e)) => println!("{seq} {a}/{b} robot {i}: error {e}"),
                None => println!("{seq} robot {i}: no report"),
            }
        }
    }
}
