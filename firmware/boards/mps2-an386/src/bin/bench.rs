//! The benchmark: reads two map files through semihosting (bench-a.cmap,
//! the model, and bench-b.cmap, the scene, from QEMU's working directory),
//! matches them on board (the scene kept as a robot keeps a received map) and prints the
//! instructions the preparation and the match took (bench.sh).
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cosem_core::map::{LocalMap, MapConfig, SceneMap, ScenePoint, VoxelSink};
use cosem_core::matching::{MatchSettings, Matcher, Pyramid};
use static_cell::ConstStaticCell;
// A robot's capacities: the bench matches what a robot can hold.
use cosem_core::robot::{MapStorage, ModelStorage, ReceivedStorage, SceneStorage, FOOTPRINT_CELL, LEVELS, VOXELS};
use cosem_core::wire::mapfile;
use cosem_mps2_an386::hostfs::read_file;
use cosem_mps2_an386::{exit, peak_stack, say, start_clock, ticks, INSTRUCTIONS_PER_TICK};

const FILE_BYTES: usize = 32 * 1024;

static FILE: ConstStaticCell<[u8; FILE_BYTES]> = ConstStaticCell::new([0; FILE_BYTES]);
static MAP_A: ConstStaticCell<MapStorage> = ConstStaticCell::new(MapStorage::new());
static MAP_B: ConstStaticCell<ReceivedStorage> = ConstStaticCell::new([ScenePoint::EMPTY; VOXELS]);
static PYR_A: ConstStaticCell<ModelStorage> = ConstStaticCell::new(ModelStorage::new());
static PYR_B: ConstStaticCell<SceneStorage> = ConstStaticCell::new(SceneStorage::new());

#[entry]
fn main() -> ! {
    exit(start_clock().is_some() && run())
}

/// Runs the benchmark; `true` when it ran.
fn run() -> bool {
    // Each static taken once (a second take would panic: exit 101).
    let (file, a, b, pa, pb) = (FILE.take(), MAP_A.take(), MAP_B.take(), PYR_A.take(), PYR_B.take());
    let config = MapConfig::with_resolution(0.5);
    // The scene as a robot holds a received map.
    let (Ok(mut ma), Ok(mut mb)) = (LocalMap::new(a, config), SceneMap::new(&mut b[..], config.resolution)) else {
        return false;
    };
    let sinks: [(&[u8], &mut dyn VoxelSink); 2] =
        [(&b"bench-a.cmap\0"[..], &mut ma), (&b"bench-b.cmap\0"[..], &mut mb)];
    for (name, map) in sinks {
        let Some(bytes) = read_file(name, file) else {
            say!("bench error=cannot read a map file");
            return false;
        };
        if let Err(e) = mapfile::read_into(bytes, map) {
            say!("bench error={}", e);
            return false;
        }
    }
    let t0 = ticks();
    let (pya, pyb) = match (
        Pyramid::build(&ma, LEVELS, FOOTPRINT_CELL, pa),
        Pyramid::build_scene(&mb, LEVELS, FOOTPRINT_CELL, pb),
    ) {
        (Ok(a), Ok(b)) => (a, b),
        (Err(e), _) | (_, Err(e)) => {
            say!("bench error=pyramid: {}", e);
            return false;
        }
    };
    let prep = ticks() - t0;
    let t1 = ticks();
    let r = Matcher::new(MatchSettings::default()).align(&pya, &pyb, &nalgebra::Isometry3::identity());
    let spent = ticks() - t1;
    let r = match r {
        Ok(r) => r,
        Err(_e) => {
            #[cfg(feature = "defmt")]
            defmt::error!("bench match failed: {}", _e);
            say!("bench error=match");
            return false;
        }
    };
    #[cfg(feature = "defmt")]
    defmt::info!("bench match: {}", r);
    let t = r.transform.translation.vector;
    say!("bench voxels={},{} coarse_entries={},{}", ma.len(), mb.len(), pya.coarse_entries(), pyb.coarse_entries());
    for (name, fp) in [("model", pya.footprint()), ("scene", pyb.footprint())] {
        if let Some(fp) = fp {
            let (w, h) = fp.size();
            say!("bench {}_footprint cell={} cells={}x{} occupied={}", name, fp.cell(), w, h, fp.occupied_len());
        }
    }
    say!(
        "bench status={} iterations={} translation={:.4},{:.4},{:.4} yaw_deg={:.4}",
        r.status.as_str(),
        r.iterations,
        t.x,
        t.y,
        t.z,
        r.transform.rotation.euler_angles().2.to_degrees()
    );
    say!(
        "bench match_instructions={} preparation_instructions={}",
        spent * INSTRUCTIONS_PER_TICK,
        prep * INSTRUCTIONS_PER_TICK
    );
    say!("bench peak_stack_bytes={}", peak_stack());
    true
}
