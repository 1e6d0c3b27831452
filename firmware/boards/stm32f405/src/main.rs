//! Robot B on an STM32F405 (`cosem robots --board-b stm32f405`): 192 KiB of
//! RAM cannot hold two maps and a matcher, so this robot is the core's
//! [`Robot::sender`]: fed its thinned points over USART1, it builds its map
//! (4,096 voxels, the main SRAM's 128 KiB), sends it over USART2 and takes
//! none, then is told robot A's result and reports it as its own `T_B_A`.
//! Everything else (link buffers, scratch, receive rings, stack) lives in
//! the 64 KiB CCM; both USARTs receive by interrupt into rings (the robot
//! sleeps with `wfi` while it waits), through the one embedded-hal-nb to
//! embedded-io adapter of `cosem-firmware`. Exit code 0 when the match
//! converged, 1 otherwise.
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::NVIC;
use cortex_m_rt::entry;
use cosem_core::matching::MatchStatus;
use cosem_core::robot::{Capacity, Machine, Meter, Poll, Robot, RobotConfig};
use cosem_firmware::serial::{IrqReceiver, RingSerial, RxInterrupt, RX_RING};
use cosem_firmware::{exit, instructions_at, millis_at, peak_stack, start_clock};
use static_cell::ConstStaticCell;
use stm32f4xx_hal::pac::{self, interrupt, Interrupt};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::serial::{Instance, Rx, RxListen};

/// The robot's capacities: a map of 28 bytes per voxel in the main SRAM's
/// 128 KiB, and nothing to match with.
const CAPACITY: Capacity = Capacity::sender(cosem_core::robot::SMALL_VOXELS);
/// SysTick's rate under QEMU's netduinoplus2 (fixed, whatever the clock
/// tree says); with `-icount shift=0` its count is an instruction count.
/// On hardware (`--features hardware`) it is the core clock the HAL set.
const QEMU_SYSTICK_HZ: u32 = 168_000_000;
static SYSTICK_HZ: AtomicU32 = AtomicU32::new(QEMU_SYSTICK_HZ);

fn systick_hz() -> u32 {
    SYSTICK_HZ.load(Ordering::Relaxed)
}

/// The robot's own region (its map), in the main SRAM (cleared in `main`:
/// the section is not zeroed at reset).
#[link_section = ".sram"]
/// A `static mut`, not a `ConstStaticCell` as the others: a cell's
/// "taken" flag in this section would start as whatever the SRAM held.
static mut OWN: MaybeUninit<[u32; CAPACITY.own_words()]> = MaybeUninit::uninit();
/// The robot's turn region: the link's Morton scratch and buffers.
static TURN: ConstStaticCell<[u32; CAPACITY.turn_words()]> = ConstStaticCell::new([0; CAPACITY.turn_words()]);

/// A HAL receiver with its interrupt (embedded-hal has no interrupt
/// traits): the UART's RXNE interrupt, held off in the NVIC while the ring
/// is full.
struct HalRx<U: Instance> {
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

static FEED_RX: IrqReceiver<HalRx<pac::USART1>, RX_RING> = IrqReceiver::new();
static LINK_RX: IrqReceiver<HalRx<pac::USART2>, RX_RING> = IrqReceiver::new();

#[interrupt]
fn USART1() {
    FEED_RX.on_interrupt();
}

#[interrupt]
fn USART2() {
    LINK_RX.on_interrupt();
}

/// This board's measures.
struct Board;

impl Meter for Board {
    fn instructions(&self) -> u64 {
        instructions_at(systick_hz())
    }
    fn peak_stack(&self) -> u32 {
        peak_stack()
    }
}

fn sleep() {
    cortex_m::asm::wfi();
}

#[entry]
fn main() -> ! {
    if start_clock().is_none() {
        exit(false);
    }
    let Some(dp) = pac::Peripherals::take() else { exit(false) };
    // The internal oscillator: QEMU models no PLL or HSE ready bits.
    let mut rcc = dp.RCC.freeze(Config::hsi());
    if cfg!(feature = "hardware") {
        SYSTICK_HZ.store(rcc.clocks.sysclk().raw(), Ordering::Relaxed);
    }
    let gpioa = dp.GPIOA.split(&mut rcc);
    let feed = dp.USART1.serial((gpioa.pa9, gpioa.pa10), 115_200.bps(), &mut rcc);
    let link = dp.USART2.serial((gpioa.pa2, gpioa.pa3), 115_200.bps(), &mut rcc);
    let (Ok(feed), Ok(link)) = (feed, link) else { exit(false) };
    let (feed_tx, feed_rx) = feed.split();
    let (link_tx, link_rx) = link.split();
    FEED_RX.install(HalRx { rx: feed_rx, irq: Interrupt::USART1 });
    LINK_RX.install(HalRx { rx: link_rx, irq: Interrupt::USART2 });
    // SAFETY: the handlers only touch their receivers, installed above.
    unsafe {
        NVIC::unmask(Interrupt::USART1);
        NVIC::unmask(Interrupt::USART2);
    }
    let mut feed = RingSerial::new(&FEED_RX, feed_tx, sleep);
    let mut link = RingSerial::new(&LINK_RX, link_tx, sleep);
    // Each cell taken once (a second take would panic: exit 101).
    let turn = TURN.take();
    // SAFETY: `main` runs once and is the only code that names `OWN`, here;
    // its words are written (zeros) before they are taken as initialised.
    let own = unsafe {
        let own = &mut *addr_of_mut!(OWN);
        core::ptr::write_bytes(own.as_mut_ptr(), 0, 1);
        own.assume_init_mut()
    };
    let Ok(mut robot) = Robot::sender(RobotConfig::default(), own, turn, CAPACITY) else { exit(false) };
    let link = core::slice::from_mut(&mut link);
    loop {
        match robot.poll(&mut feed, link, millis_at(systick_hz()), &Board) {
            Ok(Poll::Busy) => {}
            Ok(Poll::Done(report)) => exit(report.result.status == MatchStatus::Converged.code()),
            Err(_e) => {
                #[cfg(feature = "defmt")]
                defmt::error!("robot stopped at {}: {}", _e.stage(), _e);
                exit(false)
            }
        }
    }
}
