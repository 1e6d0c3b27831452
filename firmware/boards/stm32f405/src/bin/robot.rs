//! A matching robot on an STM32F405 (`cosem robots --board-a stm32f405
//! --board-b stm32f405`): the core's pair [`Robot`] in 192 KiB. Fed its
//! thinned points over USART1, it builds its map (0.7 m voxels,
//! [`Capacity::STM32F405`]), exchanges maps with its peer over USART2,
//! prepares both, searches every heading and offset when it has no prior,
//! refines, weighs the information matrix and gives its verdict, and
//! reports `T_own_peer` over USART1. Exit code 0 when the match converged,
//! 1 otherwise.
//!
//! Memory (see the crate's README): the own region (the map, then spare
//! words for pyramid buffers) and the received map fill the 128 KiB SRAM;
//! the turn region (the link's scratch and buffers, then pyramid buffers),
//! the receive rings and the stack the 64 KiB CCM. The link checks that
//! the statics leave the stack room (`memory-*.x`).
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use cortex_m_rt::entry;
use cosem_core::map::{SceneMap, ScenePoint};
use cosem_core::matching::MatchStatus;
use cosem_core::robot::{Capacity, Robot, RobotConfig};
use cosem_core::wire::feed::RobotReport;
use cosem_firmware::drive;
use cosem_firmware::serial::RingSerial;
use cosem_stm32f405::{exit, millis_at, sleep, start, systick_hz, zeroed, Board, FeedRx, LinkRx};
use static_cell::ConstStaticCell;
use stm32f4xx_hal::pac::interrupt;

const CAPACITY: Capacity = Capacity::STM32F405;

/// The SRAM's two regions, written (zeros) before they are taken: the
/// section is not zeroed at reset.
#[repr(C)]
struct Sram {
    own: [u32; CAPACITY.own_words()],
    received: [ScenePoint; CAPACITY.voxels],
}

/// A `static mut`, not a `ConstStaticCell`: a cell's "taken" flag in this
/// section would start as whatever the SRAM held.
#[link_section = ".sram"]
static mut SRAM: MaybeUninit<Sram> = MaybeUninit::uninit();
/// The turn region, in the CCM: the link's Morton scratch and buffers,
/// then pyramid buffers.
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
    // Taken once (a second take would panic: exit 101).
    let turn = TURN.take();
    // SAFETY: `main` runs once and is the only code that names `SRAM`,
    // here; its bytes are written (zeros: every field is plain integers)
    // before they are taken as initialised.
    let sram = unsafe { zeroed(addr_of_mut!(SRAM)) };
    let Sram { own, received } = sram;
    // The set-up names the voxel size; until then the received map waits
    // empty.
    let Ok(mut received) = SceneMap::new(&mut received[..], 0.5) else { exit(false) };
    let Ok(mut robot) = Robot::new(RobotConfig::default(), own, turn, CAPACITY, &mut received) else { exit(false) };
    let link = core::slice::from_mut(&mut link);
    let quiet = || FEED_RX.ring().is_empty() && LINK_RX.ring().is_empty();
    let converged = |r: &RobotReport| r.result.status == MatchStatus::Converged.code();
    drive(&mut robot, &mut feed, link, &Board, || millis_at(systick_hz()), quiet, converged)
}
