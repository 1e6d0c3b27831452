//! Ends badly on purpose, for the tests: `-append panic` panics, `-append
//! fault` reads from an address that faults. Either must end QEMU at once
//! with the firmware's panic or fault exit code, never hang.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cosem_mps2_an386::{exit, hostfs};

#[entry]
fn main() -> ! {
    let mut buf = [0u8; 128];
    let line = hostfs::command_line(&mut buf).unwrap_or(&[]);
    if line.ends_with(b"panic") {
        let depth = line.len();
        panic!("on purpose (command line of {depth} bytes)");
    }
    if line.ends_with(b"fault") {
        // SAFETY: none: this read is meant to fault (the address is not
        // mapped on the mps2 boards).
        let v = unsafe { core::ptr::read_volatile(0xF000_0000 as *const u32) };
        exit(v == 0);
    }
    exit(true)
}
