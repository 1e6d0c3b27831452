//! What the STM32F405's robots share: the core clock's rate, the two
//! USARTs (feeder USART1, link USART2) receiving by interrupt into rings
//! through the HAL and the one embedded-hal-nb to embedded-io adapter of
//! `cosem-firmware`, and the board's [`Meter`].
//!
//! Memory: a real STM32F405 has 128 KiB of SRAM at 0x20000000 and 64 KiB of
//! core-coupled memory (CCM) at 0x10000000; a robot's large regions are
//! placed in one or the other whole (`memory-hardware.x`; QEMU's
//! netduinoplus2 maps 192 KiB of SRAM in one block and `memory-qemu.x`
//! splits it the same way). The stack, the receive rings and `.bss` are in
//! the CCM; statics placed with `#[link_section = ".sram"]` in the SRAM.
#![no_std]

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::NVIC;
use cosem_core::robot::Meter;
use cosem_firmware::serial::{IrqReceiver, RxInterrupt};
use cosem_firmware::{instructions_at, peak_stack};
use stm32f4xx_hal::pac::{self, Interrupt};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::serial::{Instance, Rx, RxListen, Tx};

pub use cosem_firmware::{exit, millis_at, start_clock};

/// Bytes of the link's receive ring: a link's window (1,792 bytes) fits,
/// so a peer that sends while this robot matches is never overrun.
pub const LINK_RING: usize = 2048;
/// Bytes of the feeder's receive ring: a feeder sends nothing while the
/// robot matches, and a full ring holds the UART (its interrupt masked).
pub const FEED_RING: usize = 1024;

/// SysTick's rate under QEMU's netduinoplus2 (fixed, whatever the clock
/// tree says); with `-icount shift=0` its count is an instruction count.
/// On hardware (`--features hardware`) it is the core clock the HAL set.
const QEMU_SYSTICK_HZ: u32 = 168_000_000;
static SYSTICK_HZ: AtomicU32 = AtomicU32::new(QEMU_SYSTICK_HZ);

/// SysTick's rate.
pub fn systick_hz() -> u32 {
    SYSTICK_HZ.load(Ordering::Relaxed)
}

/// A HAL receiver with its interrupt (embedded-hal has no interrupt
/// traits): the UART's RXNE interrupt, held off in the NVIC while the ring
/// is full.
pub struct HalRx<U: Instance> {
    rx: Rx<U>,
    irq: Interrupt,
}

impl<U: Instance> embedded_hal_nb::serial::ErrorType for HalRx<U> {
    type Error = stm32f4xx_hal::serial::Error;
}

impl<U: Instance> embedded_hal_nb::serial::Read<u8> for HalRx<U>
where
    Rx<U>: embedded_hal_nb::serial::Read<u8, Error = stm32f4xx_hal::serial::Error>,
{
    fn read(&mut self) -> nb::Result<u8, Self::Error> {
        self.rx.read()
    }
}

impl<U: Instance> RxInterrupt for HalRx<U>
where
    Rx<U>: embedded_hal_nb::serial::Read<u8, Error = stm32f4xx_hal::serial::Error> + RxListen,
{
    fn listen(&mut self) {
        RxListen::listen(&mut self.rx);
    }
    fn pause(&mut self) {
        NVIC::mask(self.irq);
    }
    fn resume(&mut self) {
        // SAFETY: the handler only touches this receiver's ring.
        unsafe { NVIC::unmask(self.irq) };
    }
}

/// The feeder's receiver (USART1).
pub type FeedRx = IrqReceiver<HalRx<pac::USART1>, FEED_RING>;
/// The link's receiver (USART2; a team robot's first peer).
pub type LinkRx = IrqReceiver<HalRx<pac::USART2>, LINK_RING>;
/// A team robot's second peer's receiver (USART3).
pub type Link3Rx = IrqReceiver<HalRx<pac::USART3>, LINK_RING>;

/// A line a robot talks over, whichever USART is under it: a team robot's
/// peers are USARTs of different types, reached as `&mut dyn Port`.
pub trait Port:
    embedded_io::Read
    + embedded_io::Write
    + embedded_io::ReadReady
    + embedded_io::WriteReady
    + embedded_io::ErrorType<Error = cosem_firmware::serial::SerialError>
{
}

impl<T> Port for T where
    T: embedded_io::Read
        + embedded_io::Write
        + embedded_io::ReadReady
        + embedded_io::WriteReady
        + embedded_io::ErrorType<Error = cosem_firmware::serial::SerialError>
{
}

/// This board's measures.
pub struct Board;

impl Meter for Board {
    fn instructions(&self) -> u64 {
        instructions_at(systick_hz())
    }
    fn peak_stack(&self) -> u32 {
        peak_stack()
    }
}

/// The static behind `slot` (in `.sram`, which reset does not clear) with
/// its bytes zeroed, as a value.
///
/// # Safety
///
/// No other code names the static (call it once, from `main`), and all
/// bytes zero is a valid `T` (a type of plain integers).
pub unsafe fn zeroed<T>(slot: *mut core::mem::MaybeUninit<T>) -> &'static mut T {
    // SAFETY: the caller's promises: the only reference, zeros are a `T`.
    unsafe {
        core::ptr::write_bytes(slot, 0, 1);
        (*slot).assume_init_mut()
    }
}

/// Sleeps until an interrupt.
pub fn sleep() {
    cortex_m::asm::wfi();
}

/// Starts the clock and USART1 and USART2 at 115200 baud, installs their
/// receivers in `feed_rx` and `link_rx` and unmasks their interrupts;
/// the transmit halves, feeder's first. `None` if a peripheral is missing.
pub fn start(feed_rx: &'static FeedRx, link_rx: &'static LinkRx) -> Option<(Tx<pac::USART1>, Tx<pac::USART2>)> {
    start_clock()?;
    start_with(pac::Peripherals::take()?, feed_rx, link_rx).map(|(feed, link, _)| (feed, link))
}

/// [`start`], and USART3 (PB10/PB11) with its receiver in `link3_rx`: a
/// team robot's lines (feeder, first peer, second peer).
pub fn start_team(
    feed_rx: &'static FeedRx,
    link_rx: &'static LinkRx,
    link3_rx: &'static Link3Rx,
) -> Option<(Tx<pac::USART1>, Tx<pac::USART2>, Tx<pac::USART3>)> {
    start_clock()?;
    let (feed, link, (usart3, gpiob, mut rcc)) = start_with(pac::Peripherals::take()?, feed_rx, link_rx)?;
    let link3 = usart3.serial((gpiob.pb10, gpiob.pb11), 115_200.bps(), &mut rcc).ok()?;
    let (link3_tx, link3_rx_half) = link3.split();
    link3_rx.install(HalRx { rx: link3_rx_half, irq: Interrupt::USART3 });
    // SAFETY: the handler only touches its receiver, installed above.
    unsafe { NVIC::unmask(Interrupt::USART3) };
    Some((feed, link, link3_tx))
}

/// What [`start_with`] leaves for a third USART.
type Rest = (pac::USART3, stm32f4xx_hal::gpio::gpiob::Parts, stm32f4xx_hal::rcc::Rcc);

fn start_with(
    dp: pac::Peripherals,
    feed_rx: &'static FeedRx,
    link_rx: &'static LinkRx,
) -> Option<(Tx<pac::USART1>, Tx<pac::USART2>, Rest)> {
    // The internal oscillator: QEMU models no PLL or HSE ready bits.
    let mut rcc = dp.RCC.freeze(Config::hsi());
    if cfg!(feature = "hardware") {
        SYSTICK_HZ.store(rcc.clocks.sysclk().raw(), Ordering::Relaxed);
    }
    let gpioa = dp.GPIOA.split(&mut rcc);
    let feed = dp.USART1.serial((gpioa.pa9, gpioa.pa10), 115_200.bps(), &mut rcc).ok()?;
    let link = dp.USART2.serial((gpioa.pa2, gpioa.pa3), 115_200.bps(), &mut rcc).ok()?;
    let (feed_tx, feed_rx_half) = feed.split();
    let (link_tx, link_rx_half) = link.split();
    feed_rx.install(HalRx { rx: feed_rx_half, irq: Interrupt::USART1 });
    link_rx.install(HalRx { rx: link_rx_half, irq: Interrupt::USART2 });
    // SAFETY: the handlers only touch their receivers, installed above.
    unsafe {
        NVIC::unmask(Interrupt::USART1);
        NVIC::unmask(Interrupt::USART2);
    }
    let gpiob = dp.GPIOB.split(&mut rcc);
    Some((feed_tx, link_tx, (dp.USART3, gpiob, rcc)))
}
