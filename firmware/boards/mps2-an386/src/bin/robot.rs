//! One robot of a pair (`cosem robots`): the core's robot step machine
//! ([`cosem_core::robot::Robot`]) driven by this board: fed its scans over
//! UART1, it builds its map, exchanges maps with the other robot over UART0
//! and aligns the received map to its own, then reports over UART1. Exit
//! code 0 when the match converged, 1 otherwise (the report or failure says
//! why). Both UARTs receive by interrupt into rings, so bytes the peer
//! sends while this robot prepares or matches wait in its ring, not in a
//! one-byte UART register that a real chip would overrun. Its memory is two
//! regions of words that the core's robot hands from stage to stage by
//! ownership ([`cosem_core::robot::memory`]): the map, then the pyramids;
//! the link's buffers, then the model's copied level 0. So the robot fits
//! 512 KiB with its stack (the link checks it, `robot-budget.x`).
#![no_std]
#![no_main]

use cortex_m_rt::{entry, exception};
use cosem_core::map::{SceneMap, ScenePoint};
use cosem_core::matching::MatchStatus;
use cosem_core::robot::{Capacity, ReceivedStorage, Robot, RobotConfig, VOXELS};
use cosem_core::wire::feed::RobotReport;
use cosem_firmware::drive;
use cosem_mps2_an386::serial::{IrqReceiver, RingSerial, RX_RING};
use cosem_mps2_an386::uart::{unmask_rx, Uart, UartRx, UART0, UART1};
use cosem_mps2_an386::{exit, millis, start_clock, Board, CLOCK_HZ};
use static_cell::ConstStaticCell;

/// The robot's own region: its map, then its pyramids.
static OWN: ConstStaticCell<[u32; Capacity::BOARD.own_words()]> =
    ConstStaticCell::new([0; Capacity::BOARD.own_words()]);
/// The robot's turn region: the link's scratch and buffers, then the
/// model's copied level 0.
static TURN: ConstStaticCell<[u32; Capacity::BOARD.turn_words()]> =
    ConstStaticCell::new([0; Capacity::BOARD.turn_words()]);
static RECEIVED: ConstStaticCell<ReceivedStorage> = ConstStaticCell::new([ScenePoint::EMPTY; VOXELS]);
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
    // Each static taken once (a second take would panic: exit 101).
    let (own, turn, received) = (OWN.take(), TURN.take(), RECEIVED.take());
    // The set-up names the voxel size; until then the received map waits
    // empty.
    let Ok(mut received) = SceneMap::new(&mut received[..], 0.5) else { exit(false) };
    let Ok(mut robot) = Robot::new(RobotConfig::default(), own, turn, Capacity::BOARD, &mut received) else {
        exit(false)
    };
    let board = Board { link_bytes: || LINK_RX.ring().pushed() };
    let link = core::slice::from_mut(&mut link);
    let quiet = || FEED_RX.ring().is_empty() && LINK_RX.ring().is_empty();
    let converged = |report: &RobotReport| {
        #[cfg(feature = "defmt")]
        defmt::info!("robot {=u8}: {} after {=u32} ms of link", report.result.robot_id, report.result, report.link_ms);
        report.result.status == MatchStatus::Converged.code()
    };
    drive(&mut robot, &mut feed, link, &board, millis, quiet, converged)
}
