//! One robot of a pair (`cosem robots`): the core's robot step machine
//! ([`cosem_core::robot::Robot`]) driven by this board: fed its scans over
//! UART1, it builds its map, exchanges maps with the other robot over UART0
//! and aligns the received map to its own, then reports over UART1. Exit
//! code 0 when the match converged, 1 otherwise (the report or failure says
//! why). Both UARTs receive by interrupt into rings, so bytes the peer
//! sends while this robot prepares or matches wait in its ring, not in a
//! one-byte UART register that a real chip would overrun. Memory takes
//! turns ([`cosem_mps2_an386::turns`]): the link's buffers with the model's
//! level 0 copied out of the map, and the map with the pyramids' other
//! parts, so the robot fits 512 KiB with its stack (the link checks it,
//! `robot-budget.x`).
#![no_std]
#![no_main]

use core::mem::ManuallyDrop;
use core::ptr::addr_of_mut;
use cortex_m_rt::{entry, exception};
use cosem_core::link::LinkBuffers;
use cosem_core::map::{LocalMap, SceneMap, ScenePoint};
use cosem_core::matching::MatchStatus;
use cosem_core::matching::SplitStorage;
use cosem_core::robot::{
    map_config, Machine, MapStorage, ModelLevel0, ModelRest, Poll, ReceivedStorage, Robot, RobotConfig, SceneStorage,
    VOXELS,
};
use cosem_mps2_an386::serial::{IrqReceiver, RingSerial, RX_RING};
use cosem_mps2_an386::turns::Later;
use cosem_mps2_an386::uart::{unmask_rx, Uart, UartRx, UART0, UART1};
use cosem_mps2_an386::{exit, millis, start_clock, Board, CLOCK_HZ};
use static_cell::ConstStaticCell;

static RECEIVED: ConstStaticCell<ReceivedStorage> = ConstStaticCell::new([ScenePoint::EMPTY; VOXELS]);

/// The link's turn: its buffers and the Morton order of the map it sends.
struct LinkTurn {
    buffers: LinkBuffers,
    scratch: [u32; VOXELS],
}

/// The link's turn, then the model's copied level 0 (the larger sets the
/// size). Zeroed: the link's buffers are written when the robot starts.
union Turns {
    link: ManuallyDrop<LinkTurn>,
    level0: ManuallyDrop<ModelLevel0>,
}

/// What follows the own map in its memory: the model's coarse levels and
/// footprint, and the scene's pyramid.
struct PyramidTurn {
    model: ModelRest,
    scene: SceneStorage,
}

/// The own map, then the pyramids (the map is the larger).
union OwnTurns {
    map: ManuallyDrop<MapStorage>,
    pyramids: ManuallyDrop<PyramidTurn>,
}

static TURNS: ConstStaticCell<Turns> = ConstStaticCell::new(Turns { level0: ManuallyDrop::new(ModelLevel0::new()) });
static OWN: ConstStaticCell<OwnTurns> = ConstStaticCell::new(OwnTurns { map: ManuallyDrop::new(MapStorage::new()) });
static FEED_RX: IrqReceiver<UartRx, RX_RING> = IrqReceiver::new();
static LINK_RX: IrqReceiver<UartRx, RX_RING> = IrqReceiver::new();

/// The UARTs' receive interrupts (lines 0 and 2): each receiver
/// acknowledges its interrupt and drains its UART into its ring.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    match irqn {
        0 => LINK_RX.on_interrupt(),
        2 => FEED_RX.on_interrupt(),
        _ => {}
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
    // SAFETY: UART0 and UART1 are CMSDK UARTs of this board, each owned once here.
    let (feed, link) = unsafe { (Uart::new(UART1, CLOCK_HZ, 115_200), Uart::new(UART0, CLOCK_HZ, 115_200)) };
    let (Some((feed_rx, feed_tx)), Some((link_rx, link_tx))) = (feed.split(), link.split()) else { exit(false) };
    FEED_RX.install(feed_rx);
    LINK_RX.install(link_rx);
    // SAFETY: both receivers are installed; each handler touches its own.
    unsafe {
        unmask_rx(UART1);
        unmask_rx(UART0);
    }
    let mut feed = RingSerial::new(&FEED_RX, feed_tx, idle);
    let mut link = RingSerial::new(&LINK_RX, link_tx, idle);
    // Each static taken once (a second take would panic: exit 101); the
    // unions are then reached through pointers only, turn by turn.
    let (turns, own_turns, received) = (TURNS.take(), OWN.take(), RECEIVED.take());
    let (turns, own_turns): (*mut Turns, *mut OwnTurns) = (turns, own_turns);
    // SAFETY: the pointers come from the two unions this `main` owns
    // alone. The link's turn is borrowed now; the copied level 0 is reached
    // only when the robot prepares, after its link endpoint (and every
    // borrow of the link's turn) is gone. The map is reached through a
    // pointer until the model's level 0 has been copied out of it; the
    // pyramids' other parts only after that (see `turns`).
    let (own, scratch, buffers, model, scene) = unsafe {
        let link = addr_of_mut!((*turns).link).cast::<LinkTurn>();
        let pyramids = addr_of_mut!((*own_turns).pyramids).cast::<PyramidTurn>();
        addr_of_mut!((*link).buffers).write(LinkBuffers::new());
        (
            Later::new(addr_of_mut!((*own_turns).map).cast::<MapStorage>()),
            &mut *addr_of_mut!((*link).scratch),
            &mut *addr_of_mut!((*link).buffers),
            SplitStorage {
                level0: Later::new(addr_of_mut!((*turns).level0).cast::<ModelLevel0>()),
                rest: Later::new(addr_of_mut!((*pyramids).model)),
            },
            Later::new(addr_of_mut!((*pyramids).scene)),
        )
    };
    // The set-up names the voxel size; until then the maps wait empty.
    let (Ok(mut own), Ok(mut received)) = (LocalMap::new(own, map_config(0.5)), SceneMap::new(&mut received[..], 0.5))
    else {
        exit(false)
    };
    let mut robot = Robot::new(RobotConfig::default(), &mut own, &mut received, scratch, buffers, model, scene);
    let board = Board { link_bytes: || LINK_RX.ring().pushed() };
    let link = core::slice::from_mut(&mut link);
    loop {
        match robot.poll(&mut feed, link, millis(), &board) {
            Ok(Poll::Busy) => {
                // Nothing received: sleep until a byte or the clock's
                // wrap (a guest that spins on memory alone starves QEMU's
                // I/O thread: bytes arrived 2.6 times slower; a real chip
                // saves power).
                cortex_m::interrupt::free(|_| {
                    if FEED_RX.ring().is_empty() && LINK_RX.ring().is_empty() {
                        cortex_m::asm::wfi();
                    }
                });
            }
            Ok(Poll::Done(report)) => {
                #[cfg(feature = "defmt")]
                defmt::info!(
                    "robot {=u8}: {} after {=u32} ms of link",
                    report.result.robot_id,
                    report.result,
                    report.link_ms
                );
                exit(report.result.status == MatchStatus::Converged.code())
            }
            Err(_e) => {
                #[cfg(feature = "defmt")]
                defmt::error!("robot stopped at {}: {}", _e.stage(), _e);
                exit(false)
            }
        }
    }
}
