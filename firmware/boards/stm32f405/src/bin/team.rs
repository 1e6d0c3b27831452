//! One robot of a team on an STM32F405 (`cosem team --on-board --board
//! stm32f405`): the core's [`TeamRobot`] with
//! [`Capacity::STM32F405_TEAM`]. Fed its scans over USART1, it builds its
//! map, meets each peer over its own USART (USART2, USART3: the peers in
//! index order, itself skipped, so a team has at most three boards),
//! exchanges maps and matches, shares the estimates, checks them for
//! consistency and solves the pose graph, and reports every step over
//! USART1. Exit code 0 when it finished, 1 when it stopped.
//!
//! Memory: the map, both pyramid storages, the received map and the
//! scratch in the SRAM (a `static mut` in `.sram`, zeroed before it is
//! used); the link's buffers, the receive rings and the stack (the pose
//! graph's normal equations are on it) in the CCM.
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use cortex_m_rt::entry;
use cosem_core::link::LinkBuffers;
use cosem_core::map::{ArrayStorage, LocalMap, SceneMap, ScenePoint};
use cosem_core::matching::{ArrayPyramidStorage, ArraySceneStorage};
use cosem_core::robot::team::{TeamRobot, TABLE_WORDS};
use cosem_core::robot::{map_config, Capacity, RobotConfig};
use cosem_firmware::drive;
use cosem_firmware::serial::RingSerial;
use cosem_stm32f405::{exit, millis_at, sleep, start_team, systick_hz, zeroed, Board, FeedRx, Link3Rx, LinkRx, Port};
use static_cell::ConstStaticCell;
use stm32f4xx_hal::pac::interrupt;

const C: Capacity = Capacity::STM32F405_TEAM;
const V: usize = C.voxels;
const E: usize = C.coarse;

/// Scratch words: one per voxel (the map's order for the link, the
/// searches' caches), or the team's table.
const SCRATCH: usize = if V > TABLE_WORDS { V } else { TABLE_WORDS };

/// The SRAM's part: the map, the model's and the scene's pyramid storages,
/// the received map and the scratch.
struct Sram {
    own: ArrayStorage<V, u16>,
    model: ArrayPyramidStorage<V, E, { C.model_words }>,
    scene: ArraySceneStorage<E, { C.scene_words }>,
    received: [ScenePoint; V],
    scratch: [u32; SCRATCH],
}

/// A `static mut`, not a `ConstStaticCell`: a cell's "taken" flag in this
/// section would start as whatever the SRAM held.
#[link_section = ".sram"]
static mut SRAM: MaybeUninit<Sram> = MaybeUninit::uninit();
static LINK: ConstStaticCell<LinkBuffers> = ConstStaticCell::new(LinkBuffers::new());

static FEED_RX: FeedRx = FeedRx::new();
static LINK_RX: LinkRx = LinkRx::new();
static LINK3_RX: Link3Rx = Link3Rx::new();

#[interrupt]
fn USART1() {
    FEED_RX.on_interrupt();
}

#[interrupt]
fn USART2() {
    LINK_RX.on_interrupt();
}

#[interrupt]
fn USART3() {
    LINK3_RX.on_interrupt();
}

#[entry]
fn main() -> ! {
    let Some((feed_tx, link_tx, link3_tx)) = start_team(&FEED_RX, &LINK_RX, &LINK3_RX) else { exit(false) };
    let mut feed = RingSerial::new(&FEED_RX, feed_tx, sleep);
    let mut peer0 = RingSerial::new(&LINK_RX, link_tx, sleep);
    let mut peer1 = RingSerial::new(&LINK3_RX, link3_tx, sleep);
    // Each cell taken once (a second take would panic: exit 101).
    let buffers = LINK.take();
    // SAFETY: `main` runs once and is the only code that names `SRAM`,
    // here; every field is integers (voxels, slots, entries, normals,
    // words), so its bytes, zeroed here, are a valid value.
    let sram = unsafe { zeroed(addr_of_mut!(SRAM)) };
    let Sram { own, model, scene, received, scratch } = sram;
    // The set-up names the voxel size; until then the maps wait empty.
    let (Ok(mut own), Ok(mut received)) = (LocalMap::new(own, map_config(0.5)), SceneMap::new(&mut received[..], 0.5))
    else {
        exit(false)
    };
    let mut robot = TeamRobot::new(RobotConfig::default(), &mut own, &mut received, scratch, buffers, model, scene)
        .with_em_iterations(C.em_iterations);
    let mut peers: [&mut dyn Port; 2] = [&mut peer0, &mut peer1];
    let quiet = || FEED_RX.ring().is_empty() && LINK_RX.ring().is_empty() && LINK3_RX.ring().is_empty();
    drive(&mut robot, &mut feed, &mut peers, &Board, || millis_at(systick_hz()), quiet, |_| true)
}
