//! Robot B on an STM32F405 as a sender (`cosem robots --board-b
//! stm32f405-sender`): the core's [`Robot::sender`]. Fed its thinned points
//! over USART1, it builds its map (4,096 voxels, the main SRAM's 128 KiB),
//! sends it over USART2 and takes none, then is told robot A's result and
//! reports it as its own `T_B_A`. Everything else (link buffers, scratch,
//! receive rings, stack) lives in the 64 KiB CCM. Exit code 0 when the
//! match converged, 1 otherwise. The board's matching robot is `robot.rs`.
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use cortex_m_rt::entry;
use cosem_core::matching::MatchStatus;
use cosem_core::robot::{Capacity, Robot, RobotConfig};
use cosem_core::wire::feed::RobotReport;
use cosem_firmware::drive;
use cosem_firmware::serial::RingSerial;
use cosem_stm32f405::{exit, millis_at, sleep, start, systick_hz, zeroed, Board, FeedRx, LinkRx};
use static_cell::ConstStaticCell;
use stm32f4xx_hal::pac::interrupt;

/// The robot's capacities: a map of 28 bytes per voxel in the main SRAM's
/// 128 KiB, and nothing to match with.
const CAPACITY: Capacity = Capacity::sender(cosem_core::robot::SMALL_VOXELS);

/// The robot's own region (its map), in the main SRAM (cleared in `main`:
/// the section is not zeroed at reset).
#[link_section = ".sram"]
/// A `static mut`, not a `ConstStaticCell` as the others: a cell's
/// "taken" flag in this section would start as whatever the SRAM held.
static mut OWN: MaybeUninit<[u32; CAPACITY.own_words()]> = MaybeUninit::uninit();
/// The robot's turn region: the link's Morton scratch and buffers.
static TURN: ConstStaticCell<[u32; CAPACITY.turn_words()]> = ConstStaticCell::new([0; CAPACITY.turn_words()]);

static FEED_RX: FeedRx = FeedRx::new();
static LINK_RX: LinkRx = LinkRx::new();

#[interrupt]
fn USART1() {
    FEED_RX.on_interrupt();
}

#[interrupt]
fn USART2() {
    LINK_RX.on_interrupt();
}

#[entry]
fn main() -> ! {
    let Some((feed_tx, link_tx)) = start(&FEED_RX, &LINK_RX) else { exit(false) };
    let mut feed = RingSerial::new(&FEED_RX, feed_tx, sleep);
    let mut link = RingSerial::new(&LINK_RX, link_tx, sleep);
    // Each cell taken once (a second take would panic: exit 101).
    let turn = TURN.take();
    // SAFETY: `main` runs once and is the only code that names `OWN`, here;
    // its words are written (zeros) before they are taken as initialised.
    let own = unsafe { zeroed(addr_of_mut!(OWN)) };
    let Ok(mut robot) = Robot::sender(RobotConfig::default(), own, turn, CAPACITY) else { exit(false) };
    let link = core::slice::from_mut(&mut link);
    let quiet = || FEED_RX.ring().is_empty() && LINK_RX.ring().is_empty();
    let converged = |r: &RobotReport| r.result.status == MatchStatus::Converged.code();
    drive(&mut robot, &mut feed, link, &Board, || millis_at(systick_hz()), quiet, converged)
}
