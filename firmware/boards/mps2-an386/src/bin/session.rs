//! One robot that keeps driving (`cosem session --on-board`): the core's
//! session robot ([`cosem_core::robot::session::SessionRobot`]) driven by
//! this board. Fed its scans in rounds over UART1, each round it fuses
//! them into its bounded map, trades map updates with its peer over UART0
//! (its own for the peer's, each answered), re-estimates the peer and
//! reports the round over UART1; after the last round it reports its end.
//! Exit code 0 when it ran every round, 1 when it stopped (its last message
//! says why). Both UARTs receive by interrupt into rings. Its memory is
//! statics of the core's session sizes
//! ([`cosem_core::robot::session::SESSION_VOXELS`]), within the 1 MiB
//! budget.
#![no_std]
#![no_main]

use cortex_m_rt::{entry, exception};
use cosem_core::link::courier::CourierConfig;
use cosem_core::matching::search::SearchScratch;
use cosem_core::matching::Reach;
use cosem_core::robot::session::{
    SessionMapStorage, SessionModelStorage, SessionParts, SessionRecords, SessionRobot, SessionSceneStorage,
    SESSION_REACH, SESSION_UPDATE_BYTES, SESSION_VOXELS,
};
use cosem_core::robot::RobotConfig;
use cosem_core::session::ShadowEntry;
use cosem_firmware::drive;
use cosem_mps2_an386::serial::{IrqReceiver, RingSerial, RX_RING};
use cosem_mps2_an386::uart::{unmask_rx, Uart, UartRx, UART0, UART1};
use cosem_mps2_an386::{exit, millis, start_clock, Board, CLOCK_HZ};
use static_cell::ConstStaticCell;

static MAP: ConstStaticCell<SessionMapStorage> = ConstStaticCell::new(SessionMapStorage::new());
static COPY: ConstStaticCell<SessionMapStorage> = ConstStaticCell::new(SessionMapStorage::new());
static HELD: ConstStaticCell<SessionRecords> = ConstStaticCell::new([ShadowEntry::EMPTY; SESSION_VOXELS]);
static SENT: ConstStaticCell<SessionRecords> = ConstStaticCell::new([ShadowEntry::EMPTY; SESSION_VOXELS]);
/// Two words a voxel: the faster Morton ordering of `wire::codec`.
static SCRATCH: ConstStaticCell<[u32; 2 * SESSION_VOXELS]> = ConstStaticCell::new([0; 2 * SESSION_VOXELS]);
static OUT: ConstStaticCell<[u8; SESSION_UPDATE_BYTES]> = ConstStaticCell::new([0; SESSION_UPDATE_BYTES]);
static IN: ConstStaticCell<[u8; SESSION_UPDATE_BYTES]> = ConstStaticCell::new([0; SESSION_UPDATE_BYTES]);
static MODEL: ConstStaticCell<SessionModelStorage> = ConstStaticCell::new(SessionModelStorage::new());
static SCENE: ConstStaticCell<SessionSceneStorage> = ConstStaticCell::new(SessionSceneStorage::new());
static SEARCH: ConstStaticCell<[u32; SearchScratch::WINDOWED]> = ConstStaticCell::new([0; SearchScratch::WINDOWED]);
/// EM's memory of each sampled entry's block (72 B an entry): a prior-free
/// round's EM looks up far fewer cells.
static REACH: ConstStaticCell<[Reach; SESSION_REACH]> = ConstStaticCell::new([Reach::EMPTY; SESSION_REACH]);
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
    let parts = SessionParts {
        map: MAP.take(),
        copy: COPY.take(),
        records: (HELD.take(), SENT.take()),
        scratch: SCRATCH.take(),
        out: OUT.take(),
        input: IN.take(),
        model: MODEL.take(),
        scene: SCENE.take(),
        search: SEARCH.take(),
        reach: REACH.take(),
    };
    let Ok(mut robot) = SessionRobot::new(RobotConfig::default(), CourierConfig::default(), parts) else { exit(false) };
    let board = Board { link_bytes: || LINK_RX.ring().pushed() };
    let link = core::slice::from_mut(&mut link);
    let quiet = || FEED_RX.ring().is_empty() && LINK_RX.ring().is_empty();
    drive(&mut robot, &mut feed, link, &board, millis, quiet, |_| true)
}
