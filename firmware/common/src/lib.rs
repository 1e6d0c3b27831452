//! What every cosem board shares (the boards are crates of their own
//! under `firmware/boards/`: clocks, UARTs and memory maps differ; the
//! robot is the core's, the same on every board):
//!
//! - exit codes through semihosting, a panic handler and a hard-fault
//!   handler that end QEMU at once with their own codes ([`EXIT_PANIC`],
//!   [`EXIT_FAULT`]);
//! - the SysTick instruction clock ([`start_clock`], [`ticks`]; a board
//!   gives its SysTick rate) and the painted-stack gauge ([`peak_stack`]);
//! - [`serial`]: receive rings that interrupt handlers fill, and the one
//!   adapter from `embedded-hal-nb` serial to the `embedded-io` traits of
//!   the core's link;
//! - [`hostfs`]: semihosting file reads and the command line.
#![no_std]

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::exception;
use cortex_m_rt::ExceptionFrame;
use cortex_m_semihosting::debug;

pub mod hostfs;
pub mod serial;

#[cfg(feature = "defmt")]
use defmt_semihosting as _;

/// SysTick wraps (24-bit counter). With QEMU's `-icount shift=0` one
/// instruction is one nanosecond of virtual time, so SysTick's count at
/// the board's rate is an instruction count.
static WRAPS: AtomicU32 = AtomicU32::new(0);
const RELOAD: u32 = 0x00FF_FFFF;

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// Starts the SysTick instruction clock. `None` if the core peripherals
/// were taken already.
pub fn start_clock() -> Option<()> {
    let mut cp = cortex_m::Peripherals::take()?;
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(RELOAD);
    cp.SYST.clear_current();
    cp.SYST.enable_interrupt();
    cp.SYST.enable_counter();
    Some(())
}

/// Ticks since [`start_clock`] (wraps included).
pub fn ticks() -> u64 {
    loop {
        let w = WRAPS.load(Ordering::Relaxed);
        let v = cortex_m::peripheral::SYST::get_current();
        if WRAPS.load(Ordering::Relaxed) == w {
            return u64::from(w) * u64::from(RELOAD + 1) + u64::from(RELOAD - v);
        }
    }
}

/// Instructions executed since [`start_clock`] (nanoseconds of virtual
/// time under `-icount shift=0`) on a board whose SysTick counts `hz`.
pub fn instructions_at(hz: u32) -> u64 {
    (u128::from(ticks()) * 1_000_000_000 / u128::from(hz.max(1))) as u64
}

/// Milliseconds since [`start_clock`] on a board whose SysTick counts `hz`.
pub fn millis_at(hz: u32) -> u64 {
    ticks() / u64::from((hz / 1000).max(1))
}

/// Peak stack use (bytes): the start-up code paints the stack with
/// `STACK_PAINT_VALUE`; the lowest word no longer painted marks the peak.
pub fn peak_stack() -> u32 {
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

/// Prints one line to the host over semihosting: plain text, or in a build
/// with the `defmt` feature a defmt frame (so the whole output decodes with
/// `defmt-print`, as qemu-run.sh does).
pub fn say(args: core::fmt::Arguments<'_>) {
    #[cfg(feature = "defmt")]
    {
        use core::fmt::Write as _;
        let mut line: heapless::String<256> = heapless::String::new();
        let _ = line.write_fmt(args);
        defmt::println!("{=str}", line.as_str());
    }
    #[cfg(not(feature = "defmt"))]
    cortex_m_semihosting::hprintln!("{}", args);
}

/// `say!("...", args)`: [`say`] with `format_args!`.
#[macro_export]
macro_rules! say {
    ($($t:tt)*) => {
        $crate::say(format_args!($($t)*))
    };
}

/// Ends the program with an exit code QEMU passes on (semihosting).
pub fn exit(ok: bool) -> ! {
    debug::exit(if ok { debug::EXIT_SUCCESS } else { debug::EXIT_FAILURE });
    // Not reached under QEMU; on a board without a debugger, sleep.
    loop {
        cortex_m::asm::wfi();
    }
}

/// Runs `robot` to its end, as every board's robot does: polls it with the
/// time of `now_ms`, sleeps (`wfi`, interrupts masked while it checks)
/// whenever it is busy and `quiet` says no byte waits in any ring (a guest
/// that spins on memory alone starves QEMU's I/O thread; a real chip saves
/// power), and exits with `ok(report)` when it is done, 1 when it stops
/// (it told its feeder why).
pub fn drive<F, L, T, M>(
    robot: &mut M,
    feed: &mut F,
    ports: &mut [L],
    meter: &T,
    now_ms: impl Fn() -> u64,
    quiet: impl Fn() -> bool,
    ok: impl Fn(&M::Report) -> bool,
) -> !
where
    M: cosem_core::robot::Machine<F, L, T>,
{
    loop {
        match robot.poll(feed, ports, now_ms(), meter) {
            Ok(cosem_core::robot::Poll::Busy) => cortex_m::interrupt::free(|_| {
                if quiet() {
                    cortex_m::asm::wfi();
                }
            }),
            Ok(cosem_core::robot::Poll::Done(report)) => exit(ok(&report)),
            Err(_e) => {
                #[cfg(feature = "defmt")]
                defmt::error!("robot stopped at {}: {}", _e.stage(), _e);
                exit(false)
            }
        }
    }
}

/// Exit code of a firmware that panicked (the core's, which the host reads).
pub const EXIT_PANIC: u32 = cosem_core::robot::EXIT_PANIC as u32;
/// Exit code of a firmware that took a hard fault (e.g. its stack ran into
/// the statics).
pub const EXIT_FAULT: u32 = cosem_core::robot::EXIT_FAULT as u32;

/// Ends the program with any exit code (semihosting `SYS_EXIT_EXTENDED`:
/// `debug::exit` passes only 0 or 1).
pub fn exit_with(code: u32) -> ! {
    // SAFETY: semihosting call 0x20 takes a pointer to two words: the
    // reason (ADP_Stopped_ApplicationExit) and the exit code.
    unsafe {
        cortex_m_semihosting::syscall(0x20, &[0x2_0026usize, code as usize]);
    }
    loop {
        cortex_m::asm::wfi();
    }
}

/// A panic ends QEMU at once with [`EXIT_PANIC`] (never a silent hang),
/// after one line on the host's stderr.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    cortex_m::interrupt::disable();
    cortex_m_semihosting::heprintln!("firmware panicked: {}", info);
    exit_with(EXIT_PANIC)
}

/// A hard fault ends QEMU at once with [`EXIT_FAULT`].
#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    cortex_m_semihosting::heprintln!("firmware hard fault at pc {:#010x}", frame.pc());
    exit_with(EXIT_FAULT)
}
