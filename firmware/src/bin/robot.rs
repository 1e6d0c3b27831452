//! One robot of a pair (`cosem robots`): fed its scans by a host over UART1,
//! it builds its map on board, exchanges maps with the other robot over
//! UART0 with the link protocol, aligns the received map to its own (from
//! the prior the host gave, or with none from both maps' semantic
//! landmarks, reusing the link's scratch), and reports over UART1. Exit code 0 when the
//! match converged, 1 otherwise (the report or failure says why).
#![no_std]
#![no_main]

use core::fmt::Write as _;
use core::ptr::addr_of_mut;
use cortex_m_rt::entry;
use cosem_core::geometry::from_rows;
use cosem_core::link::{Clock, Endpoint, LinkConfig};
use cosem_core::map::LocalMap;
use cosem_core::matching::MatchStatus;
use cosem_core::robot::{
    self, FeedMessage, GlobalReport, MapStorage, ModelStorage, RobotMessage, RobotReport, SceneStorage, Setup, Stage,
    VOXELS,
};
use cosem_core::wire::frame::{encode_frame, Deframer, MAX_FRAME, MAX_PAYLOAD};
use cosem_core::wire::message::MatchReport;
use cosem_firmware::uart::{Uart, UART0, UART1};
use cosem_firmware::{exit, instructions, millis, peak_stack, start_clock, CLOCK_HZ};
use embedded_io::{Read, ReadReady, Write};

/// Give up when the feeder sends nothing for this long (ms of the robot's
/// clock). Generous: under -icount the clock runs with the instructions the
/// robot polls with, so a host busy with other emulators can leave a long
/// gap of virtual time between two fed bytes (a 60 s limit tripped once in
/// a loaded test run); the host's own deadline bounds a run anyway.
const FEED_SILENCE_MS: u64 = 300_000;

static mut OWN: MapStorage = MapStorage::new();
static mut RECEIVED: MapStorage = MapStorage::new();
static mut MODEL: ModelStorage = ModelStorage::new();
static mut SCENE: SceneStorage = SceneStorage::new();
static mut SCRATCH: [u32; VOXELS] = [0; VOXELS];

/// The robot's clock: SysTick (virtual time under QEMU's -icount).
struct SysClock;

impl Clock for SysClock {
    fn now_ms(&self) -> u64 {
        millis()
    }
}

/// A failure to report: where, and a message.
struct Failure {
    stage: Stage,
    message: heapless::String<96>,
}

fn fail(stage: Stage, what: impl core::fmt::Display) -> Failure {
    let mut message = heapless::String::new();
    let _ = write!(message, "{what}");
    Failure { stage, message }
}

/// Sends one message to the host.
fn send(host: &mut Uart, msg: &RobotMessage<'_>) {
    let mut payload = [0u8; MAX_PAYLOAD];
    let mut frame = [0u8; MAX_FRAME];
    if let Ok(n) = msg.encode(&mut payload) {
        if let Ok(len) = encode_frame(&payload[..n], &mut frame) {
            let _ = host.write_all(&frame[..len]);
            let _ = host.flush();
        }
    }
}

#[entry]
fn main() -> ! {
    if start_clock().is_none() {
        exit(false);
    }
    // SAFETY: UART0 and UART1 are CMSDK UARTs of this board, each owned once here.
    let (mut host, mut link) = unsafe { (Uart::new(UART1, CLOCK_HZ, 115_200), Uart::new(UART0, CLOCK_HZ, 115_200)) };
    match run(&mut host, &mut link) {
        Ok(report) => {
            send(&mut host, &RobotMessage::Report(report));
            exit(report.result.status() == Some(MatchStatus::Converged))
        }
        Err(f) => {
            send(&mut host, &RobotMessage::Failed { stage: f.stage, message: &f.message });
            exit(false)
        }
    }
}

/// Reads the next good feed frame and copies its payload into `out`;
/// returns its length. Fails after [`FEED_SILENCE_MS`] without a byte.
fn next_frame(
    host: &mut Uart,
    deframer: &mut Deframer,
    out: &mut [u8; MAX_PAYLOAD],
    received: u32,
) -> Result<usize, Failure> {
    let mut last = millis();
    loop {
        if !host.read_ready().unwrap_or(false) {
            if millis() - last > FEED_SILENCE_MS {
                return Err(fail(Stage::Feed, format_args!("feeder silent after {received} points")));
            }
            continue;
        }
        let mut b = [0u8; 1];
        let _ = host.read(&mut b);
        last = millis();
        match deframer.push(b[0]) {
            Ok(None) => {}
            Ok(Some(payload)) => {
                let n = payload.len().min(MAX_PAYLOAD);
                out[..n].copy_from_slice(&payload[..n]);
                return Ok(n);
            }
            Err(e) => return Err(fail(Stage::Feed, e)),
        }
    }
}

fn run(host: &mut Uart, link: &mut Uart) -> Result<RobotReport, Failure> {
    // SAFETY: `run` is called once; each static is borrowed exactly once here.
    let (own, received, model, scene, scratch) = unsafe {
        (
            &mut *addr_of_mut!(OWN),
            &mut *addr_of_mut!(RECEIVED),
            &mut *addr_of_mut!(MODEL),
            &mut *addr_of_mut!(SCENE),
            &mut *addr_of_mut!(SCRATCH),
        )
    };
    // Feed: the set-up, then the scans.
    let mut deframer = Deframer::new();
    let mut payload = [0u8; MAX_PAYLOAD];
    let n = next_frame(host, &mut deframer, &mut payload, 0)?;
    let setup: Setup = match FeedMessage::decode(&payload[..n]) {
        Ok(FeedMessage::Setup(s)) => s,
        Ok(_) => return Err(fail(Stage::Feed, cosem_core::robot::FeedError::Order)),
        Err(e) => return Err(fail(Stage::Feed, e)),
    };
    let config = robot::map_config(setup.resolution);
    let mut own = LocalMap::new(own, config).map_err(|e| fail(Stage::Map, e))?;
    let mut received = LocalMap::new(received, config).map_err(|e| fail(Stage::Map, e))?;
    let (mut points, mut map_instructions) = (0u32, 0u64);
    loop {
        let n = next_frame(host, &mut deframer, &mut payload, points)?;
        match FeedMessage::decode(&payload[..n]) {
            Ok(FeedMessage::Points { data, .. }) => {
                let t0 = instructions();
                points += robot::insert_points(&mut own, data).map_err(|e| fail(Stage::Map, e))?;
                map_instructions += instructions() - t0;
            }
            Ok(FeedMessage::EndOfFeed { points: sent, .. }) => {
                if sent != points {
                    return Err(fail(Stage::Feed, "point count differs from the feeder's"));
                }
                break;
            }
            Ok(FeedMessage::Setup(_)) => return Err(fail(Stage::Feed, cosem_core::robot::FeedError::Order)),
            Err(e) => return Err(fail(Stage::Feed, e)),
        }
    }
    // Exchange maps with the peer.
    let config = LinkConfig { silence_ms: setup.silence_ms, ..LinkConfig::default() };
    let t_link = millis();
    let stats = {
        let mut endpoint = Endpoint::new(
            config,
            setup.robot_id,
            u32::from(setup.robot_id),
            0,
            Some((&own, &mut scratch[..])),
            Some(&mut received),
        )
        .map_err(|e| fail(Stage::Link, e))?;
        endpoint.run(link, &SysClock, || {}).map_err(|e| fail(Stage::Link, e))?
    };
    let link_ms = (millis() - t_link) as u32;
    // Align the received map (scene) to ours (model); the link is done
    // with the scratch, the landmark search reuses it.
    let prior = setup.prior.as_ref().map(from_rows);
    let mut marks = [0u64; 4];
    let (result, located) = robot::align(&own, &received, prior.as_ref(), scratch, model, scene, |k| {
        marks[usize::from(k)] = instructions()
    })
    .map_err(|e| fail(Stage::Match, e))?;
    Ok(RobotReport {
        result: MatchReport::new(setup.robot_id, &result),
        points,
        map_voxels: own.len() as u32,
        received_voxels: received.len() as u32,
        bytes_sent: stats.bytes_sent,
        bytes_received: stats.bytes_received,
        retransmissions: stats.retransmissions,
        link_ms,
        map_instructions,
        prepare_instructions: marks[1] - marks[0],
        locate_instructions: marks[2] - marks[1],
        match_instructions: marks[3] - marks[2],
        global: located.as_ref().map(GlobalReport::from),
        peak_stack: peak_stack(),
    })
}
