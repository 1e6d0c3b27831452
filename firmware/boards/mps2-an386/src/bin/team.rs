//! One robot of a team (`cosem team --on-board`): the core's team robot
//! ([`cosem_core::robot::team::TeamRobot`]) driven by this board. Fed its
//! scans over UART1, it builds its map, meets each peer over its own UART
//! (UART0, 2, 3, 4: the peers in index order, itself skipped, so a team
//! has at most five boards), exchanges maps and matches, shares the
//! estimates, checks them for consistency and solves the pose graph, and
//! reports every step over UART1. Exit code 0 when it finished, 1 when it
//! stopped (its last message says why).
#![no_std]
#![no_main]

use core::ptr::addr_of_mut;
use cortex_m_rt::entry;
use cosem_core::link::LinkBuffers;
use cosem_core::map::LocalMap;
use cosem_core::robot::team::TeamRobot;
use cosem_core::robot::{map_config, MapStorage, ModelStorage, RobotConfig, SceneStorage, VOXELS};
use cosem_mps2_an386::uart::{Uart, UART0, UART1, UART2, UART3, UART4};
use cosem_mps2_an386::{exit, millis, start_clock, Board, CLOCK_HZ};

static mut OWN: MapStorage = MapStorage::new();
static mut RECEIVED: MapStorage = MapStorage::new();
static mut MODEL: ModelStorage = ModelStorage::new();
static mut SCENE: SceneStorage = SceneStorage::new();
static mut SCRATCH: [u32; VOXELS] = [0; VOXELS];
static mut LINK: LinkBuffers = LinkBuffers::new();

#[entry]
fn main() -> ! {
    if start_clock().is_none() {
        exit(false);
    }
    // SAFETY: the five CMSDK UARTs of this board, each owned once here.
    let (mut feed, mut peers) = unsafe {
        let uart = |base| Uart::new(base, CLOCK_HZ, 115_200);
        (uart(UART1), [uart(UART0), uart(UART2), uart(UART3), uart(UART4)])
    };
    // SAFETY: `main` runs once; each static is borrowed exactly once here.
    let (own, received, model, scene, scratch, buffers) = unsafe {
        (
            &mut *addr_of_mut!(OWN),
            &mut *addr_of_mut!(RECEIVED),
            &mut *addr_of_mut!(MODEL),
            &mut *addr_of_mut!(SCENE),
            &mut *addr_of_mut!(SCRATCH),
            &mut *addr_of_mut!(LINK),
        )
    };
    // The set-up names the voxel size; until then the maps wait empty.
    let (Ok(mut own), Ok(mut received)) =
        (LocalMap::new(own, map_config(0.5)), LocalMap::new(received, map_config(0.5)))
    else {
        exit(false)
    };
    let mut robot = TeamRobot::new(RobotConfig::default(), &mut own, &mut received, scratch, buffers, model, scene);
    loop {
        match robot.poll(&mut feed, &mut peers, millis(), &Board) {
            Ok(false) => {}
            Ok(true) => exit(true),
            Err(_e) => {
                #[cfg(feature = "defmt")]
                defmt::error!("team robot stopped at {}: {}", _e.stage(), _e);
                exit(false)
            }
        }
    }
}
