//! The emulator process of a board: QEMU started with its UARTs on TCP
//! ports of this process, its serial ports accepted, its exit codes read
//! (a panic, a hard fault) and every instance reaped by a deadline; the
//! feeder's side of a robot's feeder line.

use crate::boards::board::Board;
use std::io::Write;
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

/// An mps2-an386 QEMU with `serials` as its UARTs, its standard error
/// kept for the board's messages.
pub(crate) fn qemu(board: Board, elf: &Path, serials: &[Option<u16>]) -> std::io::Result<Child> {
    board.qemu_command(elf, serials).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::piped()).spawn()
}

/// Waits for every QEMU to exit, killing those still running at
/// `deadline`; their exit codes (`None`: killed).
pub(crate) fn reap(children: &mut [Child], deadline: Instant) -> Vec<Option<i32>> {
    let mut codes = Vec::new();
    for c in children {
        let code = loop {
            match c.try_wait() {
                Ok(Some(s)) => break s.code(),
                Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
                _ => {
                    let _ = c.kill();
                    let _ = c.wait();
                    break None;
                }
            }
        };
        codes.push(code);
    }
    codes
}

pub(crate) fn accept(listener: &TcpListener, deadline: Instant) -> Result<TcpStream, String> {
    crate::lines::transport::accept_within(listener, deadline)
        .map_err(|e| format!("QEMU did not connect its serial port: {e}"))
}

/// The feeder's side of a robot's feeder line: the feed goes out once the
/// robot said it listens ([`RobotMessage::Ready`]: a UART that is not yet
/// enabled drops what arrives), on a thread of its own, while the robot's
/// messages are read here.
pub(crate) struct FeederLine {
    conn: Option<TcpStream>,
    feed: Vec<u8>,
    writer: Option<std::thread::JoinHandle<std::io::Result<TcpStream>>>,
}

impl FeederLine {
    pub(crate) fn new(conn: TcpStream, feed: Vec<u8>) -> Self {
        FeederLine { conn: Some(conn), feed, writer: None }
    }

    /// The robot is ready: start feeding (once).
    pub(crate) fn ready(&mut self) {
        if let Some(mut conn) = self.conn.take() {
            let feed = std::mem::take(&mut self.feed);
            self.writer = Some(std::thread::spawn(move || conn.write_all(&feed).map(|_| conn)));
        }
    }

    /// Waits for the feed to be written (or to fail).
    pub(crate) fn finish(self) {
        if let Some(w) = self.writer {
            let _ = w.join();
        }
    }
}

/// Feeds one board over `conn` (once it said it listens) and hands each
/// other message it sends to `on_message` until that says it was the last
/// (`true`); why it ended otherwise: the deadline passed, the robot closed
/// its line, the line failed.
pub(crate) fn feed_and_collect(
    conn: TcpStream,
    feed: Vec<u8>,
    deadline: Instant,
    mut on_message: impl FnMut(&[u8]) -> bool,
) -> Result<(), String> {
    use cosem_core::wire::feed::RobotMessage;
    use std::io::Read;
    let mut reader = conn.try_clone().map_err(|e| e.to_string())?;
    let mut line = FeederLine::new(conn, feed);
    let mut deframer = cosem_core::wire::frame::Deframer::new();
    let mut buf = [0u8; 1024];
    let ended = 'read: loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            break Err("no last message before the deadline".to_string());
        }
        let _ = reader.set_read_timeout(Some(left.min(Duration::from_millis(500))));
        let k = match reader.read(&mut buf) {
            Ok(0) => break Err("the robot closed its feeder line".to_string()),
            Ok(k) => k,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => continue,
            Err(e) => break Err(e.to_string()),
        };
        for &b in &buf[..k] {
            if let Ok(Some(payload)) = deframer.push(b) {
                if RobotMessage::decode(payload) == Ok(RobotMessage::Ready) {
                    line.ready();
                    continue;
                }
                if on_message(payload) {
                    break 'read Ok(());
                }
            }
        }
    };
    drop(reader);
    line.finish();
    ended
}

/// Exit code of a firmware that panicked (its panic handler exits through
/// semihosting at once).
pub const EXIT_PANIC: i32 = cosem_core::robot::EXIT_PANIC as i32;
/// Exit code of a firmware that took a hard fault.
pub const EXIT_FAULT: i32 = cosem_core::robot::EXIT_FAULT as i32;

/// The stage a robot that said nothing stopped at: the firmware itself
/// when QEMU's exit code says it panicked or faulted, else the host.
pub(crate) fn firmware_stage(code: Option<i32>) -> &'static str {
    match code {
        Some(EXIT_PANIC | EXIT_FAULT) => "firmware",
        _ => "host",
    }
}

/// Why a robot said nothing, with what its exit code tells.
pub(crate) fn lost_reason(why: &str, code: Option<i32>) -> String {
    match code {
        Some(EXIT_PANIC) => format!("the firmware panicked (exit {EXIT_PANIC}; QEMU's stderr has the message): {why}"),
        Some(EXIT_FAULT) => {
            format!("the firmware took a hard fault (exit {EXIT_FAULT}: a stack overflow or a bad address): {why}")
        }
        None => format!("{why}; QEMU killed at the deadline"),
        Some(_) => why.to_string(),
    }
}
