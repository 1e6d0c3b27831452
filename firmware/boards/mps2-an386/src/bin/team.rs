//! One robot of a team (`cosem team --on-board`): the core's team robot
//! ([`cosem_core::robot::team::TeamRobot`]) driven by this board. Fed its
//! scans over UART1, it builds its map, meets each peer over its own UART
//! (UART0, 2, 3, 4: the peers in index order, itself skipped, so a team
//! has at most five boards), exchanges maps and matches, shares the
//! estimates, checks them for consistency and solves the pose graph, and
//! reports every step over UART1. Exit code 0 when it finished, 1 when it
//! stopped (its last message says why). Every UART receives by interrupt
//! into a 4 KiB ring.
#![no_std]
#![no_main]

use cortex_m_rt::{entry, exception};
use cosem_core::link::LinkBuffers;
use cosem_core::map::{LocalMap, SceneMap, ScenePoint};
use cosem_core::robot::team::TeamRobot;
use cosem_core::robot::{map_config, MapStorage, ModelStorage, ReceivedStorage, RobotConfig, SceneStorage, VOXELS};
use cosem_firmware::drive;
use cosem_mps2_an386::serial::{IrqReceiver, RingSerial, RX_RING};
use cosem_mps2_an386::uart::{unmask_rx, Uart, UartRx, UART0, UART1, UART2, UART3, UART4};
use cosem_mps2_an386::{exit, millis, start_clock, Board, CLOCK_HZ};
use static_cell::ConstStaticCell;

static OWN: ConstStaticCell<MapStorage> = ConstStaticCell::new(MapStorage::new());
static RECEIVED: ConstStaticCell<ReceivedStorage> = ConstStaticCell::new([ScenePoint::EMPTY; VOXELS]);
static MODEL: ConstStaticCell<ModelStorage> = ConstStaticCell::new(ModelStorage::new());
static SCENE: ConstStaticCell<SceneStorage> = ConstStaticCell::new(SceneStorage::new());
static SCRATCH: ConstStaticCell<[u32; VOXELS]> = ConstStaticCell::new([0; VOXELS]);
static LINK: ConstStaticCell<LinkBuffers> = ConstStaticCell::new(LinkBuffers::new());

/// Each UART's receive ring: UART1 the feeder's, UART0, 2, 3, 4 the peers'.
type Receiver = IrqReceiver<UartRx, RX_RING>;
static RX: [Receiver; 5] = [Receiver::new(), Receiver::new(), Receiver::new(), Receiver::new(), Receiver::new()];
/// The UARTs in the order of `RX`.
const UARTS: [usize; 5] = [UART1, UART0, UART2, UART3, UART4];

/// The UARTs' receive interrupts: acknowledged, then drained into their
/// rings (a peer that starts the next round while this robot matches
/// fills its ring instead of overrunning a one-byte register).
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    let at = match irqn {
        2 => 0,
        0 => 1,
        4 => 2,
        18 => 3,
        20 => 4,
        _ => return,
    };
    if let Some(rx) = RX.get(at) {
        rx.on_interrupt();
    }
}

fn idle() {
    cortex_m::asm::wfi();
}

#[entry]
fn main() -> ! {
    if start_clock().is_none() {
        exit(false);
    }
    // SAFETY: the five CMSDK UARTs of this board, each owned once here;
    // each interrupt is unmasked once its receiver is installed.
    let [Some(feed), Some(p0), Some(p1), Some(p2), Some(p3)] = UARTS.map(|base| unsafe {
        let (rx, tx) = Uart::new(base, CLOCK_HZ, 115_200).split()?;
        let receiver = RX.iter().zip(UARTS).find(|(_, b)| *b == base)?.0;
        receiver.install(rx);
        unmask_rx(base);
        Some(RingSerial::new(receiver, tx, idle))
    }) else {
        exit(false)
    };
    let (mut feed, mut peers) = (feed, [p0, p1, p2, p3]);
    // Each static taken once (a second take would panic: exit 101).
    let (own, received, model, scene, scratch, buffers) =
        (OWN.take(), RECEIVED.take(), MODEL.take(), SCENE.take(), SCRATCH.take(), LINK.take());
    // The set-up names the voxel size; until then the maps wait empty.
    let (Ok(mut own), Ok(mut received)) = (LocalMap::new(own, map_config(0.5)), SceneMap::new(&mut received[..], 0.5))
    else {
        exit(false)
    };
    let mut robot = TeamRobot::new(RobotConfig::default(), &mut own, &mut received, scratch, buffers, model, scene);
    // The peers' rings (all but the feeder's).
    let board = Board { link_bytes: || RX.iter().skip(1).fold(0u32, |n, rx| n.wrapping_add(rx.ring().pushed())) };
    let quiet = || RX.iter().all(|r| r.ring().is_empty());
    drive(&mut robot, &mut feed, &mut peers, &board, millis, quiet, |_| true)
}
