//! cosem firmware: a robot's computer (Cortex-M4F, QEMU mps2-an386).
//!
//! The budget build (default) runs the core's self-test on the target
//! (`check`): maps two robots' views of a street corner, passes one map
//! through the wire encoding, matches it, and prints every figure (and the
//! instructions the match took) over semihosting, so a host can check them
//! bit for bit against its own run of the same code. Every buffer is a
//! static sized at compile time, in a RAM budget of 1 MiB that the linker
//! enforces (memory-budget.x). The `bench` feature builds the benchmark
//! (`bench`, 4 MiB layout): two map files matched on board (bench.sh).
#![no_std]
#![no_main]

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception};
use cortex_m_semihosting::debug;
use panic_halt as _;

#[cfg(feature = "bench")]
mod bench;
#[cfg(not(feature = "bench"))]
mod check;
#[cfg_attr(feature = "bench", allow(dead_code))]
mod uart;

#[cfg(feature = "defmt")]
use defmt_semihosting as _;

/// SysTick wraps (24-bit counter): with QEMU's `-icount shift=0` one
/// instruction is one nanosecond of virtual time and SysTick counts the
/// 25 MHz system clock, so a tick is 40 instructions.
pub(crate) static WRAPS: AtomicU32 = AtomicU32::new(0);
const RELOAD: u32 = 0x00FF_FFFF;
pub(crate) const INSTRUCTIONS_PER_TICK: u64 = 40;

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// Ticks since start (wraps included).
pub(crate) fn ticks() -> u64 {
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
#[cfg_attr(feature = "bench", allow(dead_code))]
pub(crate) fn peak_stack() -> u32 {
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
    #[cfg(feature = "bench")]
    return Ok(bench::run());
    #[cfg(not(feature = "bench"))]
    check::run()
}
