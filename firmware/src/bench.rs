//! The benchmark build: reads two map files through semihosting, matches
//! them on board and prints the instructions the match took.

use crate::{ticks, INSTRUCTIONS_PER_TICK};
use core::ptr::addr_of_mut;
use cortex_m_semihosting::{hprintln, nr, syscall};
use cosem_core::map::{ArrayStorage, LocalMap, MapConfig};
use cosem_core::matching::{ArrayPyramidStorage, MatchSettings, Matcher, Pyramid};
use cosem_core::wire::mapfile;

const VOXELS: usize = 8192;
const FILE_BYTES: usize = 64 * 1024;
type MapStorage = ArrayStorage<VOXELS>;
type PyrStorage = ArrayPyramidStorage<{ 3 * VOXELS }, 65_536>;

static mut FILE: [u8; FILE_BYTES] = [0; FILE_BYTES];
static mut MAP_A: MapStorage = MapStorage::new();
static mut MAP_B: MapStorage = MapStorage::new();
static mut PYR_A: PyrStorage = PyrStorage::new();
static mut PYR_B: PyrStorage = PyrStorage::new();

/// Reads a whole host file (path NUL-terminated) into `buf`.
fn read_file<'a>(path: &[u8], buf: &'a mut [u8]) -> Option<&'a [u8]> {
    // SAFETY: semihosting calls with a NUL-terminated path and a buffer we own.
    unsafe {
        let fd = syscall!(OPEN, path.as_ptr(), 1usize, path.len() - 1) as isize;
        if fd < 0 {
            return None;
        }
        let len = syscall!(FLEN, fd) as usize;
        let ok = len <= buf.len() && syscall!(READ, fd, buf.as_mut_ptr(), len) == 0;
        syscall!(CLOSE, fd);
        let _ = nr::CLOSE;
        if ok {
            buf.get(..len)
        } else {
            None
        }
    }
}

/// Runs the benchmark; `true` when it ran.
pub fn run() -> bool {
    // SAFETY: called once from `main`; each static is borrowed once.
    let (file, a, b, pa, pb) = unsafe {
        (
            &mut *addr_of_mut!(FILE),
            &mut *addr_of_mut!(MAP_A),
            &mut *addr_of_mut!(MAP_B),
            &mut *addr_of_mut!(PYR_A),
            &mut *addr_of_mut!(PYR_B),
        )
    };
    let config = MapConfig::with_resolution(0.5);
    let (Ok(mut ma), Ok(mut mb)) = (LocalMap::new(a, config), LocalMap::new(b, config)) else { return false };
    for (name, map) in [(&b"bench-a.cmap\0"[..], &mut ma), (&b"bench-b.cmap\0"[..], &mut mb)] {
        let Some(bytes) = read_file(name, file) else {
            hprintln!("bench error=cannot read a map file");
            return false;
        };
        if let Err(e) = mapfile::read_into(bytes, map) {
            hprintln!("bench error={:?}", e);
            return false;
        }
    }
    let t0 = ticks();
    let (Ok(pya), Ok(pyb)) = (Pyramid::build(&ma, 3, 1.0, pa), Pyramid::build(&mb, 3, 1.0, pb)) else {
        hprintln!("bench error=pyramid");
        return false;
    };
    let prep = ticks() - t0;
    let t1 = ticks();
    let r = Matcher::new(MatchSettings::default()).align(&pya, &pyb, &nalgebra::Isometry3::identity());
    let spent = ticks() - t1;
    let Ok(r) = r else {
        hprintln!("bench error=match");
        return false;
    };
    let t = r.transform.translation.vector;
    hprintln!("bench voxels={},{}", ma.len(), mb.len());
    hprintln!(
        "bench status={} iterations={} translation={:.4},{:.4},{:.4} yaw_deg={:.4}",
        r.status.as_str(),
        r.iterations,
        t.x,
        t.y,
        t.z,
        r.transform.rotation.euler_angles().2.to_degrees()
    );
    hprintln!(
        "bench match_instructions={} preparation_instructions={}",
        spent * INSTRUCTIONS_PER_TICK,
        prep * INSTRUCTIONS_PER_TICK
    );
    true
}
