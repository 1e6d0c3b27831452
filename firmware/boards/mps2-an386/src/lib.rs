//! cosem on QEMU's `mps2-an386` (Cortex-M4F): the board's part. What the
//! boards share comes from `cosem-firmware` (re-exported here); this crate
//! adds the CMSDK UART driver, the clock rate and the memory map (a 1 MiB
//! RAM budget the linker enforces, `memory-budget.x`: an STM32H7-class
//! robot computer).
//!
//! - `selftest` (the default `cargo run`): the core's self-test on the
//!   target, every figure printed for the host to compare bit for bit;
//! - `bench`: two map files matched on board (bench.sh);
//! - `robot`: one robot of a pair (`cosem robots`);
//! - `team`: one robot of a team of up to five (`cosem team --on-board`):
//!   UART1 its feeder line, UART0, 2, 3 and 4 its peers;
//! - `session`: one robot that keeps driving (`cosem session --on-board`):
//!   fed in rounds over UART1, trading map updates with its peer over
//!   UART0;
//! - `crash`: panics or faults on purpose (`-append panic|fault`), for the
//!   tests of the exit codes.
#![no_std]

pub use cosem_firmware::*;

pub mod uart;

/// System (and peripheral) clock of the board (Hz): SysTick counts it.
pub const CLOCK_HZ: u32 = 25_000_000;
/// Instructions per SysTick tick under `-icount shift=0` (1 ns each).
pub const INSTRUCTIONS_PER_TICK: u64 = 40;

extern "C" {
    fn DefaultHandler();
}

/// The interrupt part of the vector table (the CMSDK peripherals' 32
/// lines), every entry the default handler until a driver takes one.
#[link_section = ".vector_table.interrupts"]
#[no_mangle]
#[used]
pub static __INTERRUPTS: [unsafe extern "C" fn(); 32] = [DefaultHandler; 32];

/// Instructions executed since [`start_clock`]: SysTick's count times 40,
/// without the 128-bit division of [`instructions_at`] (a thousand
/// instructions inside every window a robot measures: a robot measures
/// each fed message's mapping).
pub fn instructions() -> u64 {
    ticks() * INSTRUCTIONS_PER_TICK
}

/// Milliseconds of virtual time since [`start_clock`].
pub fn millis() -> u64 {
    millis_at(CLOCK_HZ)
}

/// This board's measures for a robot: SysTick instructions, the painted
/// stack, and the bytes its link rings took (the binary that owns them
/// says how to count them).
pub struct Board {
    /// Bytes the link lines' receive interrupts took so far (wrapping).
    pub link_bytes: fn() -> u32,
}

impl cosem_core::robot::Meter for Board {
    fn instructions(&self) -> u64 {
        instructions()
    }
    fn peak_stack(&self) -> u32 {
        peak_stack()
    }
    fn link_bytes(&self) -> u32 {
        (self.link_bytes)()
    }
}
