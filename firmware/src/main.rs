//! cosem firmware: a robot's computer (Cortex-M4F, QEMU mps2-an386).
//!
//! For now it runs the core's self-test on the target: maps two robots'
//! views of a street corner, passes one map through the wire encoding,
//! matches it, and prints every figure (and the instructions the match took)
//! over semihosting, so a host can check them bit for bit against its own
//! run of the same code. Every buffer is a static sized at compile time, in
//! a RAM budget of 1 MiB that the linker enforces (memory.x).
#![no_std]
#![no_main]

use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception};
use cortex_m_semihosting::{debug, hprintln};
use panic_halt as _;

mod uart;

#[cfg(feature = "defmt")]
use defmt_semihosting as _;

use core::fmt::Write as _;
use cosem_core::map::{ArrayStorage, LocalMap, MapConfig};
use cosem_core::matching::ArrayPyramidStorage;
use cosem_core::selftest::{self, FOOTPRINT_WORDS, MAP_VOXELS, PYRAMID_ENTRIES, RESOLUTION};

type MapStorage = ArrayStorage<MAP_VOXELS>;
type PyrStorage = ArrayPyramidStorage<PYRAMID_ENTRIES, FOOTPRINT_WORDS>;

static mut MAP_A: MapStorage = MapStorage::new();
static mut MAP_B: MapStorage = MapStorage::new();
static mut RECEIVED: MapStorage = MapStorage::new();
static mut PYR_A: PyrStorage = PyrStorage::new();
static mut PYR_B: PyrStorage = PyrStorage::new();
static mut SCRATCH: [u32; MAP_VOXELS] = [0; MAP_VOXELS];

/// SysTick wraps (24-bit counter): with QEMU's `-icount shift=0` one
/// instruction is one nanosecond of virtual time and SysTick counts the
/// 25 MHz system clock, so a tick is 40 instructions.
static WRAPS: AtomicU32 = AtomicU32::new(0);
const RELOAD: u32 = 0x00FF_FFFF;
const INSTRUCTIONS_PER_TICK: u64 = 40;

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// Ticks since start (wraps included).
fn ticks() -> u64 {
    loop {
        let w = WRAPS.load(Ordering::Relaxed);
        let v = cortex_m::peripheral::SYST::get_current();
        if WRAPS.load(Ordering::Relaxed) == w {
            return u64::from(w) * u64::from(RELOAD + 1) + u64::from(RELOAD - v);
        }
    }
}

/// Peak stack use (bytes): the start-up code paints the stack with
/// `STACK_PAINT_VALUE`; the lowest word no longer painted marks the peak.
fn peak_stack() -> u32 {
    extern "C" {
        static _stack_start: u32;
        static _stack_end: u32;
    }
    // SAFETY: the linker script defines both symbols as the bounds of the
    // stack region; only their addresses are taken, and the words between
    // them are plain RAM, read with volatile reads.
    unsafe {
        let top = core::ptr::addr_of!(_stack_start) as usize;
        let mut p = core::ptr::addr_of!(_stack_end) as usize;
        while p < top && core::ptr::read_volatile(p as *const u32) == cortex_m_rt::STACK_PAINT_VALUE {
            p += 4;
        }
        (top - p) as u32
    }
}

#[entry]
fn main() -> ! {
    let code = match run() {
        Ok(true) => debug::EXIT_SUCCESS,
        _ => debug::EXIT_FAILURE,
    };
    debug::exit(code);
    // Not reached under QEMU; on a board without a debugger, sleep.
    loop {
        cortex_m::asm::wfi();
    }
}

fn run() -> Result<bool, ()> {
    let mut cp = cortex_m::Peripherals::take().ok_or(())?;
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(RELOAD);
    cp.SYST.clear_current();
    cp.SYST.enable_interrupt();
    cp.SYST.enable_counter();
    // SAFETY: `run` is called once, from `main`, before anything else could
    // touch these statics; each is borrowed exactly once here.
    let (a, b, r, pa, pb, scratch) = unsafe {
        (
            &mut *addr_of_mut!(MAP_A),
            &mut *addr_of_mut!(MAP_B),
            &mut *addr_of_mut!(RECEIVED),
            &mut *addr_of_mut!(PYR_A),
            &mut *addr_of_mut!(PYR_B),
            &mut *addr_of_mut!(SCRATCH),
        )
    };
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
            hprintln!("selftest error={:?}", e);
            return Ok(false);
        }
    };
    let bits = report.transform_bits();
    hprintln!("selftest voxels={},{}", report.voxels[0], report.voxels[1]);
    hprintln!("selftest digests={:08x},{:08x}", report.digests[0], report.digests[1]);
    hprintln!("selftest wire_bytes={} wire_ok={}", report.wire_bytes, report.wire_ok);
    hprintln!(
        "selftest transform={:08x},{:08x},{:08x},{:08x},{:08x},{:08x},{:08x}",
        bits[0],
        bits[1],
        bits[2],
        bits[3],
        bits[4],
        bits[5],
        bits[6]
    );
    hprintln!(
        "selftest status={} iterations={} inliers={} overlap={:08x}",
        report.result.status.as_str(),
        report.result.iterations,
        report.result.inliers,
        report.result.overlap.to_bits()
    );
    hprintln!(
        "selftest match_instructions={} total_instructions={}",
        spent * INSTRUCTIONS_PER_TICK,
        total * INSTRUCTIONS_PER_TICK
    );
    hprintln!("selftest peak_stack_bytes={}", peak_stack());
    #[cfg(feature = "defmt")]
    defmt::info!(
        "selftest {} after {} iterations, {} instructions",
        report.result.status,
        report.result.iterations,
        spent * INSTRUCTIONS_PER_TICK
    );
    // The same verdict on UART0 through the embedded-io driver (the link's
    // path to the other robot).
    // SAFETY: UART0 is a CMSDK UART of this board and nothing else uses it.
    let mut uart0 = unsafe { uart::Uart::new(uart::UART0, 25_000_000, 115_200) };
    let mut line: heapless::String<96> = heapless::String::new();
    let _ = writeln!(line, "cosem selftest {} {:08x}", report.result.status.as_str(), report.digests[1]);
    embedded_io::Write::write_all(&mut uart0, line.as_bytes()).map_err(|_| ())?;
    embedded_io::Write::flush(&mut uart0).map_err(|_| ())?;
    Ok(report.wire_ok)
}
