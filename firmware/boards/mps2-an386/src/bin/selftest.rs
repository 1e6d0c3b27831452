//! The core's self-test on the target (mapping, wire, matching), every
//! figure printed for the host to compare bit for bit; the verdict also goes
//! out of UART0 through the embedded-io driver.
#![no_std]
#![no_main]

use core::fmt::Write as _;
use cortex_m_rt::entry;
use cosem_core::map::{ArrayStorage, LocalMap, MapConfig};
use cosem_core::matching::ArrayPyramidStorage;
use cosem_core::selftest::{self, FOOTPRINT_WORDS, MAP_VOXELS, PYRAMID_ENTRIES, RESOLUTION};
use cosem_mps2_an386::{exit, peak_stack, say, start_clock, ticks, uart, CLOCK_HZ, INSTRUCTIONS_PER_TICK};
use static_cell::ConstStaticCell;

type MapStorage = ArrayStorage<MAP_VOXELS>;
type PyrStorage = ArrayPyramidStorage<MAP_VOXELS, PYRAMID_ENTRIES, FOOTPRINT_WORDS>;

static MAP_A: ConstStaticCell<MapStorage> = ConstStaticCell::new(MapStorage::new());
static MAP_B: ConstStaticCell<MapStorage> = ConstStaticCell::new(MapStorage::new());
static RECEIVED: ConstStaticCell<MapStorage> = ConstStaticCell::new(MapStorage::new());
static PYR_A: ConstStaticCell<PyrStorage> = ConstStaticCell::new(PyrStorage::new());
static PYR_B: ConstStaticCell<PyrStorage> = ConstStaticCell::new(PyrStorage::new());
static SCRATCH: ConstStaticCell<[u32; MAP_VOXELS]> = ConstStaticCell::new([0; MAP_VOXELS]);

#[entry]
fn main() -> ! {
    exit(start_clock().is_some() && run() == Ok(true))
}

/// Runs the self-test and prints its figures.
fn run() -> Result<bool, ()> {
    // Each static taken once (a second take would panic: exit 101).
    let (a, b, r, pa, pb, scratch) =
        (MAP_A.take(), MAP_B.take(), RECEIVED.take(), PYR_A.take(), PYR_B.take(), SCRATCH.take());
    let config = MapConfig::with_resolution(RESOLUTION);
    let mut map_a = LocalMap::new(a, config).map_err(|_| ())?;
    let mut map_b = LocalMap::new(b, config).map_err(|_| ())?;
    let mut received = LocalMap::new(r, config).map_err(|_| ())?;
    let mut chunk = [0u8; 240];
    let (mut start, mut spent) = (0u64, 0u64);
    let t0 = ticks();
    let report = selftest::run(&mut map_a, &mut map_b, &mut received, scratch, &mut chunk, pa, pb, |before| {
        if before {
            start = ticks();
        } else {
            spent = ticks() - start;
        }
    });
    let total = ticks() - t0;
    let report = match report {
        Ok(r) => r,
        Err(e) => {
            #[cfg(feature = "defmt")]
            defmt::error!("selftest failed: {}", e);
            say!("selftest error={:?}", e);
            return Ok(false);
        }
    };
    // In a defmt build the core's own types go out with deferred formatting
    // (only their fields cross the line); the key=value lines below are for
    // the host's bit-for-bit comparison.
    #[cfg(feature = "defmt")]
    defmt::info!("selftest match: {}", report.result);
    say!("{}", report);
    say!(
        "selftest match_instructions={} total_instructions={}",
        spent * INSTRUCTIONS_PER_TICK,
        total * INSTRUCTIONS_PER_TICK
    );
    say!("selftest peak_stack_bytes={}", peak_stack());
    // The same verdict on UART0 through the embedded-io driver (the link's
    // path to the other robot).
    // SAFETY: UART0 is a CMSDK UART of this board and nothing else uses it.
    let mut uart0 = unsafe { uart::Uart::new(uart::UART0, CLOCK_HZ, 115_200) };
    let mut line: heapless::String<96> = heapless::String::new();
    let _ = writeln!(line, "cosem selftest {} {:08x}", report.result.status.as_str(), report.digests[1]);
    embedded_io::Write::write_all(&mut uart0, line.as_bytes()).map_err(|_| ())?;
    embedded_io::Write::flush(&mut uart0).map_err(|_| ())?;
    Ok(report.wire_ok)
}
