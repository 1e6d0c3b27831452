//! The benchmark: reads two map files through semihosting (bench-a.cmap,
//! the model, and bench-b.cmap, the scene, from QEMU's working directory),
//! matches them on board (the scene kept as a robot keeps a received map) and prints the
//! instructions the preparation and the match took (bench.sh); then what the
//! link's deframer costs per received byte, on frames of the scene file's
//! bytes as the link shapes them for a clean line, 1% and 5% of bytes
//! substituted, dropped and duplicated alike (seeded).
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
    deframe_costs(&file[..]);
    say!("bench peak_stack_bytes={}", peak_stack());
    true
}

/// Prints what the deframer costs per received byte on frames of `data`
/// shaped as the link shapes them at 0, 1, 5, 10 and 20% byte errors.
fn deframe_costs(data: &[u8]) {
    for (rate, chunk, parity) in [(0u32, 300usize, 0usize), (100, 80, 6), (500, 35, 8), (1000, 20, 8), (2000, 8, 8)] {
        let (bytes, frames, ok, instructions) = deframe_cost(data, rate, chunk, parity);
        say!(
            "bench deframe errors_per_10k={} chunk={} parity={} bytes={} frames={} decoded={} instructions_per_byte={}",
            rate,
            chunk,
            parity,
            bytes,
            frames,
            ok,
            instructions / u64::from(bytes.max(1))
        );
    }
    // Blocks, as the link shapes them where bytes go missing often.
    for (rate, segment, spares) in [(500u32, 14usize, 4usize), (1000, 10, 11), (2000, 6, 32)] {
        let shape = cosem_core::wire::BlockShape { segment, parity: 4, spares };
        let (bytes, blocks, ok, instructions) = block_cost(data, rate, shape);
        say!(
            "bench blocks errors_per_10k={} segment={} parity=4 spares={} bytes={} blocks={} decoded={} instructions_per_byte={}",
            rate,
            segment,
            spares,
            bytes,
            blocks,
            ok,
            instructions / u64::from(bytes.max(1))
        );
    }
}

/// The damage's fixed seed.
const SEED: u64 = 0x2545_F491_4F6C_DD1D;

/// The next of a xorshift sequence.
fn xorshift(state: &mut u64) -> u64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    *state
}

/// Feeds `line` to `push` one byte at a time: how many bytes completed a
/// payload, and the instructions it took.
fn timed(line: &[u8], mut push: impl FnMut(u8) -> bool) -> (u32, u64) {
    let t0 = ticks();
    let ok = line.iter().map(|&c| u32::from(push(c))).sum();
    (ok, (ticks() - t0) * INSTRUCTIONS_PER_TICK)
}

/// A byte stream's damage: each byte substituted, dropped or duplicated
/// (a third each) with probability `rate` in 10,000, from `next`.
fn damage(b: u8, rate: u32, next: &mut impl FnMut() -> u64) -> [Option<u8>; 2] {
    if (next() % 10_000) < u64::from(rate) {
        match next() % 3 {
            0 => [Some(b ^ ((next() as u8) | 1)), None],
            1 => [None, None],
            _ => [Some(b), Some(b)],
        }
    } else {
        [Some(b), None]
    }
}

/// As `deframe_cost`, for blocks of `shape` carrying 302 bytes of `data`
/// each (a 300-byte chunk and its message header) through a block
/// deframer: bytes received, blocks sent, blocks decoded, instructions.
fn block_cost(data: &[u8], rate: u32, shape: cosem_core::wire::BlockShape) -> (u32, u32, u32, u64) {
    let mut deframer = cosem_core::wire::BlockDeframer::new();
    let mut rng = SEED;
    let mut next = move || xorshift(&mut rng);
    let (mut bytes, mut blocks, mut ok, mut spent) = (0u32, 0u32, 0u32, 0u64);
    let mut line = [0u8; 2400];
    for part in data.chunks(302).take(30) {
        let mut len = 0;
        let sent =
            cosem_core::wire::encode_block(part, shape, |bs: &[u8]| -> Result<(), cosem_core::wire::FrameError> {
                for &b in bs {
                    for c in damage(b, rate, &mut next).into_iter().flatten() {
                        if let Some(slot) = line.get_mut(len) {
                            *slot = c;
                            len += 1;
                        }
                    }
                }
                Ok(())
            });
        if sent.is_err() {
            return (0, 0, 0, 0);
        }
        blocks += 1;
        let (got, took) = timed(line.get(..len).unwrap_or(&[]), |c| matches!(deframer.push_frame(c), Ok(Some(_))));
        (ok, spent, bytes) = (ok + got, spent + took, bytes + len as u32);
    }
    (bytes, blocks, ok, spent)
}

/// Frames of `chunk` bytes of `data` with `parity` parity bytes, each byte
/// damaged with probability `rate` in 10,000 (substituted, dropped or
/// duplicated, a third each, from a fixed seed), through a deframer: the
/// bytes received, frames sent, frames decoded and the instructions the
/// deframer took.
fn deframe_cost(data: &[u8], rate: u32, chunk: usize, parity: usize) -> (u32, u32, u32, u64) {
    let mut deframer = cosem_core::wire::Deframer::new();
    let (mut frame, mut rng) = ([0u8; cosem_core::wire::MAX_FRAME], SEED);
    let (mut bytes, mut frames, mut ok, mut spent) = (0u32, 0u32, 0u32, 0u64);
    let mut next = move || xorshift(&mut rng);
    let mut line = [0u8; 2 * cosem_core::wire::MAX_FRAME];
    for part in data.chunks(chunk).take(400) {
        let Ok(n) = cosem_core::wire::encode_frame_parity(part, parity, &mut frame) else { return (0, 0, 0, 0) };
        frames += 1;
        // The frame as the line delivers it, then through the deframer.
        let mut len = 0;
        for &b in frame.get(..n).unwrap_or(&[]) {
            for c in damage(b, rate, &mut next).into_iter().flatten() {
                if let Some(slot) = line.get_mut(len) {
                    *slot = c;
                    len += 1;
                }
            }
        }
        let (got, took) = timed(line.get(..len).unwrap_or(&[]), |c| matches!(deframer.push(c), Ok(Some(_))));
        (ok, spent, bytes) = (ok + got, spent + took, bytes + len as u32);
    }
    (bytes, frames, ok, spent)
}
