//! The CMSDK APB UART of the mps2 boards, behind the `embedded-io` traits
//! the core's link speaks, so a real board's HAL UART drops in instead.
//!
//! Registers (ARM CMSDK): DATA +0x0, STATE +0x4 (bit 0 TX full, bit 1 RX
//! full), CTRL +0x8 (bit 0 TX enable, bit 1 RX enable), BAUDDIV +0x10.

use core::convert::Infallible;
use core::ptr::{read_volatile, write_volatile};

/// Base addresses of the UARTs (`-serial` options 0 to 4 in QEMU).
pub const UART0: usize = 0x4000_4000;
/// UART1 (the second `-serial` option).
pub const UART1: usize = 0x4000_5000;
/// UART2 (the third `-serial`): a team robot's second peer line.
pub const UART2: usize = 0x4000_6000;
/// UART3: a team robot's third peer line.
pub const UART3: usize = 0x4000_7000;
/// UART4: a team robot's fourth peer line.
pub const UART4: usize = 0x4000_9000;

const DATA: usize = 0x0;
const STATE: usize = 0x4;
const CTRL: usize = 0x8;
const BAUDDIV: usize = 0x10;
const TX_FULL: u32 = 1 << 0;
const RX_FULL: u32 = 1 << 1;

/// Cycles to wait between two polls of an idle UART. At 115200 baud a byte
/// takes about 2,000 cycles of the 25 MHz clock, so this costs no latency;
/// it spares the bus. Under QEMU every register read takes the emulator's
/// global lock, and a guest reading STATE back to back can keep the
/// emulator's I/O thread from delivering the bytes it waits for (seen as a
/// feed that stalled mid-way while the host machine was loaded).
const POLL_BACKOFF_CYCLES: u32 = 500;

fn backoff() {
    cortex_m::asm::delay(POLL_BACKOFF_CYCLES);
}

/// One UART.
pub struct Uart {
    base: usize,
}

impl Uart {
    /// Takes the UART at `base`, enables transmitter and receiver, and sets
    /// the baud divider for `baud` from a `clock_hz` peripheral clock.
    ///
    /// # Safety
    /// `base` must be the address of a CMSDK UART not in use elsewhere.
    pub unsafe fn new(base: usize, clock_hz: u32, baud: u32) -> Self {
        let uart = Uart { base };
        // SAFETY: the caller guarantees `base` is a CMSDK UART we own.
        unsafe {
            uart.write_reg(BAUDDIV, (clock_hz / baud.max(1)).max(16));
            uart.write_reg(CTRL, 0b11);
        }
        uart
    }

    /// # Safety
    /// `offset` must be a register of this UART.
    unsafe fn reg(&self, offset: usize) -> u32 {
        // SAFETY: a register of the UART this value owns.
        unsafe { read_volatile((self.base + offset) as *const u32) }
    }

    /// # Safety
    /// `offset` must be a register of this UART.
    unsafe fn write_reg(&self, offset: usize, value: u32) {
        // SAFETY: a register of the UART this value owns.
        unsafe { write_volatile((self.base + offset) as *mut u32, value) }
    }

    fn state(&self) -> u32 {
        // SAFETY: STATE is a register of this UART.
        unsafe { self.reg(STATE) }
    }
}

impl embedded_io::ErrorType for Uart {
    type Error = Infallible;
}

impl embedded_io::Write for Uart {
    /// Blocks until the first byte fits, then sends what fits without waiting.
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        let mut n = 0;
        for &b in buf {
            if n > 0 && self.state() & TX_FULL != 0 {
                break;
            }
            while self.state() & TX_FULL != 0 {
                backoff();
            }
            // SAFETY: DATA is a register of this UART.
            unsafe { self.write_reg(DATA, u32::from(b)) };
            n += 1;
        }
        Ok(n)
    }

    fn flush(&mut self) -> Result<(), Infallible> {
        while self.state() & TX_FULL != 0 {
            backoff();
        }
        Ok(())
    }
}

impl embedded_io::WriteReady for Uart {
    /// Whether the transmitter takes a byte now.
    fn write_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.state() & TX_FULL == 0)
    }
}

impl embedded_io::ReadReady for Uart {
    /// Whether a byte is there; when not, waits [`POLL_BACKOFF_CYCLES`]
    /// first, so a loop over `read_ready` does not hammer the UART.
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        let ready = self.state() & RX_FULL != 0;
        if !ready {
            backoff();
        }
        Ok(ready)
    }
}

impl embedded_io::Read for Uart {
    /// Blocks until a byte arrives, then returns what is there.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        if buf.is_empty() {
            return Ok(0);
        }
        while self.state() & RX_FULL == 0 {
            backoff();
        }
        let mut n = 0;
        for slot in buf.iter_mut() {
            if self.state() & RX_FULL == 0 {
                break;
            }
            // SAFETY: DATA is a register of this UART.
            *slot = unsafe { self.reg(DATA) } as u8;
            n += 1;
        }
        Ok(n)
    }
}

/// INTSTATUS / INTCLEAR (+0xC): bit 1 is the receive interrupt.
const INTCLEAR: usize = 0xC;
/// CTRL bit 3: raise the receive interrupt when a byte arrives.
const RX_INT_ENABLE: u32 = 1 << 3;
const RX_INT: u32 = 1 << 1;

/// The NVIC line of each UART's receive interrupt (the CMSDK combined
/// numbering of the mps2 boards: UART n's RX is line 2n for n < 3, then
/// 18 and 20).
pub fn rx_irq(base: usize) -> Option<u16> {
    match base {
        UART0 => Some(0),
        UART1 => Some(2),
        UART2 => Some(4),
        UART3 => Some(18),
        UART4 => Some(20),
        _ => None,
    }
}

/// An NVIC line by number, for `cortex_m`'s mask and unmask.
#[derive(Clone, Copy)]
struct Line(u16);

// SAFETY: the numbers are lines of this board's NVIC (`rx_irq`).
unsafe impl cortex_m::interrupt::InterruptNumber for Line {
    fn number(self) -> u16 {
        self.0
    }
}

/// A UART's receiver, interrupt-driven: what an HAL's `embedded-hal-nb`
/// reader plus its interrupt switch would be on a real board.
pub struct UartRx {
    base: usize,
    line: Line,
}

/// A UART's transmitter (`embedded-hal-nb` serial).
pub struct UartTx {
    base: usize,
}

impl Uart {
    /// The receiver and transmitter halves, for interrupt-driven reception
    /// ([`cosem_firmware::serial::IrqReceiver`]); `None` for a base with
    /// no known receive interrupt.
    pub fn split(self) -> Option<(UartRx, UartTx)> {
        let line = Line(rx_irq(self.base)?);
        Some((UartRx { base: self.base, line }, UartTx { base: self.base }))
    }
}

impl embedded_hal_nb::serial::ErrorType for UartRx {
    type Error = Infallible;
}

impl embedded_hal_nb::serial::Read<u8> for UartRx {
    fn read(&mut self) -> nb::Result<u8, Infallible> {
        let uart = Uart { base: self.base };
        if uart.state() & RX_FULL == 0 {
            return Err(nb::Error::WouldBlock);
        }
        // SAFETY: DATA is a register of this UART.
        Ok(unsafe { uart.reg(DATA) } as u8)
    }
}

impl cosem_firmware::serial::RxInterrupt for UartRx {
    /// Clears the receive interrupt (INTCLEAR) of this UART.
    fn acknowledge(&mut self) {
        // SAFETY: INTCLEAR of the CMSDK UART this receiver owns (made by
        // `Uart::split` from a UART taken with `Uart::new`).
        unsafe { write_volatile((self.base + INTCLEAR) as *mut u32, RX_INT) }
    }
    fn listen(&mut self) {
        let uart = Uart { base: self.base };
        // SAFETY: CTRL of this UART; the interrupt is unmasked by the board.
        unsafe { uart.write_reg(CTRL, uart.reg(CTRL) | RX_INT_ENABLE) };
    }
    fn pause(&mut self) {
        cortex_m::peripheral::NVIC::mask(self.line);
    }
    fn resume(&mut self) {
        // SAFETY: the line's handler only touches its own receiver.
        unsafe { cortex_m::peripheral::NVIC::unmask(self.line) };
    }
}

impl embedded_hal_nb::serial::ErrorType for UartTx {
    type Error = Infallible;
}

impl embedded_hal_nb::serial::Write<u8> for UartTx {
    fn write(&mut self, byte: u8) -> nb::Result<(), Infallible> {
        let uart = Uart { base: self.base };
        if uart.state() & TX_FULL != 0 {
            return Err(nb::Error::WouldBlock);
        }
        // SAFETY: DATA is a register of this UART.
        unsafe { uart.write_reg(DATA, u32::from(byte)) };
        Ok(())
    }
    fn flush(&mut self) -> nb::Result<(), Infallible> {
        if (Uart { base: self.base }).state() & TX_FULL != 0 {
            return Err(nb::Error::WouldBlock);
        }
        Ok(())
    }
}

/// Unmasks UART `base`'s receive interrupt in the NVIC.
///
/// # Safety
/// Its handler must be ready (the receiver installed).
pub unsafe fn unmask_rx(base: usize) {
    if let Some(n) = rx_irq(base) {
        // SAFETY: the caller's promise.
        unsafe { cortex_m::peripheral::NVIC::unmask(Line(n)) };
    }
}
