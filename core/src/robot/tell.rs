//! A one-sided exchange's last step: a robot that cannot hold its peer's
//! map (a small microcontroller) sends its own map and takes none; the
//! peer matches and then tells it the result over the same line, as a
//! [`ShareMessage::Estimate`] (`T_peer_me`, status, information), resent
//! until acknowledged. The small robot reports the inverse as its own
//! `T_me_peer`.

use crate::link::LinkConfig;
use crate::wire::frame::{Deframer, MAX_FRAME};
use crate::wire::share::{Estimate, ShareMessage};
use embedded_io::{Read, ReadReady, Write, WriteReady};

/// How often the result goes out again until acknowledged (ms).
const RESEND_MS: u64 = 250;

/// An I/O error on the line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct LineError;

/// Reads what the line holds; calls `on` for every share message from it.
fn read_messages<L: Read + ReadReady>(
    port: &mut L,
    deframer: &mut Deframer,
    mut on: impl FnMut(ShareMessage),
) -> Result<(), LineError> {
    let mut buf = [0u8; 64];
    while port.read_ready().map_err(|_| LineError)? {
        let n = port.read(&mut buf).map_err(|_| LineError)?;
        if n == 0 {
            break;
        }
        for &b in buf.get(..n).unwrap_or(&[]) {
            // The map exchange's last frames (acknowledgements) are not
            // share messages: skipped.
            if let Ok(Some(payload)) = deframer.push(b) {
                if let Ok(msg) = ShareMessage::decode(payload) {
                    on(msg);
                }
            }
        }
    }
    Ok(())
}

fn send<L: Write>(port: &mut L, msg: &ShareMessage) -> Result<(), LineError> {
    let mut frame = [0u8; MAX_FRAME];
    let len = msg.to_frame(&mut frame).map_err(|_| LineError)?;
    port.write_all(frame.get(..len).unwrap_or(&[])).map_err(|_| LineError)?;
    port.flush().map_err(|_| LineError)
}

/// The robot that matched: tells its peer the result until acknowledged.
pub(super) struct Teller {
    estimate: Estimate,
    last_sent: Option<u64>,
    started: u64,
    deframer: Deframer,
}

impl Teller {
    /// Tells `estimate` (`T_a_b`, `a` this robot, `b` the peer) from `now`.
    pub(super) fn new(estimate: Estimate, now: u64) -> Self {
        Teller { estimate, last_sent: None, started: now, deframer: Deframer::new() }
    }

    /// `Ok(true)` when the peer acknowledged, or it stayed silent for the
    /// link's silence time (the result is this robot's own either way: a
    /// peer that never hears it fails on its side).
    pub(super) fn step<L: Read + Write + ReadReady + WriteReady>(
        &mut self,
        port: &mut L,
        now: u64,
        config: &LinkConfig,
    ) -> Result<bool, LineError> {
        let (me, peer) = (self.estimate.a, self.estimate.b);
        let mut acked = false;
        read_messages(port, &mut self.deframer, |msg| {
            if let ShareMessage::Ack { from, held, .. } = msg {
                acked |= from == peer && held & (1 << me) != 0;
            }
        })?;
        if acked {
            return Ok(true);
        }
        let due = self.last_sent.is_none_or(|t| now.saturating_sub(t) >= RESEND_MS);
        if due && port.write_ready().map_err(|_| LineError)? {
            send(port, &ShareMessage::Estimate(self.estimate))?;
            self.last_sent = Some(now);
        }
        Ok(now.saturating_sub(self.started) > u64::from(config.silence_ms))
    }
}

/// What an [`Awaiter`] ended with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Awaited {
    /// Still waiting (or lingering to answer resends).
    Busy,
    /// The peer's estimate `T_peer_me`, acknowledged.
    Told(Estimate),
    /// Nothing came within the silence time.
    Silent,
}

/// The robot that took no map: waits for its peer's result.
pub(super) struct Awaiter {
    me: u8,
    peer: u8,
    started: u64,
    told: Option<(Estimate, u64)>,
    deframer: Deframer,
}

impl Awaiter {
    /// Waits for `peer`'s estimate of `T_peer_me` from `now`.
    pub(super) fn new(me: u8, peer: u8, now: u64) -> Self {
        Awaiter { me, peer, started: now, told: None, deframer: Deframer::new() }
    }

    /// Acknowledges every copy of the estimate (an acknowledgement may be
    /// lost); done a linger time after the first.
    pub(super) fn step<L: Read + Write + ReadReady + WriteReady>(
        &mut self,
        port: &mut L,
        now: u64,
        config: &LinkConfig,
    ) -> Result<Awaited, LineError> {
        let (me, peer) = (self.me, self.peer);
        let mut got = None;
        read_messages(port, &mut self.deframer, |msg| {
            if let ShareMessage::Estimate(e) = msg {
                if e.a == peer && e.b == me {
                    got = Some(e);
                }
            }
        })?;
        if let Some(e) = got {
            if self.told.is_none() {
                self.told = Some((e, now));
            }
            send(port, &ShareMessage::Ack { from: me, held: 1 << peer, finished: true })?;
        }
        match self.told {
            Some((e, at)) if now.saturating_sub(at) >= u64::from(config.linger_ms) => Ok(Awaited::Told(e)),
            Some(_) => Ok(Awaited::Busy),
            None if now.saturating_sub(self.started) > u64::from(config.silence_ms) => Ok(Awaited::Silent),
            None => Ok(Awaited::Busy),
        }
    }
}
