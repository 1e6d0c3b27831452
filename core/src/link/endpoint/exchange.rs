//! One exchange of an endpoint: its state apart from its buffers, the
//! bytes read into frames and messages, the `Hello`, the acknowledgements
//! and what ends the exchange.

use super::*;

/// An endpoint's state apart from its buffers.
pub(super) struct Exchange<'a, M: VoxelStorage, R: VoxelSink, O: Borrow<LocalMap<M>>> {
    config: LinkConfig,
    robot_id: u8,
    resolution: f32,
    pub(super) tx: Option<Tx<'a, M, O>>,
    pub(super) rx: Rx<'a, R>,
    deframer: BlockDeframer,
    line: LineEstimate,
    /// Frames sized and protected for the line as the peer's frames show it
    /// (recomputed when one arrives).
    shape: FrameShape,
    started: bool,
    last_heard: u64,
    /// When any byte last arrived, whole frame or not: the line is alive.
    last_byte: u64,
    /// We said we are finished (at this time).
    finished_at: Option<u64>,
    peer_finished: bool,
    /// What the peer's `Hello` said: whether it takes our map (`None`
    /// until heard).
    pub(super) peer_takes_map: Option<bool>,
    /// The peer's robot id, from its `Hello`.
    pub(super) peer_id: Option<u8>,
    /// When our last `Hello` went out: sent again until the peer's is heard.
    hello_at: u64,
    /// The peer has not heard our `Hello` (its own said so): answer it.
    answer_hello: bool,
    failed: Option<LinkError>,
    pub(super) stats: LinkStats,
}

/// Parity of a `Hello`: it is sent once, and the damage it arrives with is
/// the peer's first measure of the line.
const HELLO_PARITY: usize = 16;

impl<'a, M: VoxelStorage, R: VoxelSink, O: Borrow<LocalMap<M>>> Exchange<'a, M, R, O> {
    /// The exchange of an endpoint that sends `tx` (if any) and receives into
    /// `staging` (if any), its maps of voxels of `resolution` metres.
    pub(super) fn new(
        config: LinkConfig,
        (robot_id, resolution): (u8, f32),
        tx: Option<Tx<'a, M, O>>,
        staging: Option<&'a mut R>,
    ) -> Self {
        Exchange {
            config,
            robot_id,
            resolution,
            tx,
            rx: Rx::new(staging),
            deframer: BlockDeframer::new(),
            line: LineEstimate::default(),
            shape: FrameShape::initial(&config),
            started: false,
            last_heard: 0,
            last_byte: 0,
            finished_at: None,
            peer_finished: false,
            peer_takes_map: None,
            peer_id: None,
            hello_at: 0,
            answer_hello: false,
            failed: None,
            stats: LinkStats::default(),
        }
    }

    /// Whether the peer holds our whole map (or takes none of it).
    pub(super) fn sent(&self) -> bool {
        self.tx.as_ref().is_none_or(|t| t.complete) || self.peer_takes_map == Some(false)
    }

    /// One step of the endpoint; a failure is kept, and told the peer.
    pub(super) fn step<IO: Read + Write + ReadReady + WriteReady>(
        &mut self,
        io: &mut IO,
        now: u64,
        buffers: &mut LinkBuffers,
    ) -> Result<Progress, LinkError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        let r = self.step_inner(io, now, buffers);
        // Lingering only serves the peer: if it hung up, we are done.
        if matches!(r, Err(LinkError::Io(_))) && self.finished_at.is_some() {
            return Ok(Progress::Done);
        }
        if let Err(e) = r {
            self.failed = Some(e);
            // Tell the peer, best effort, so it does not wait for nothing.
            let reason = match e {
                LinkError::TooLarge { .. } => AbortReason::TooLarge,
                LinkError::Decode(_) => AbortReason::BadChunk,
                LinkError::Digest => AbortReason::Digest,
                LinkError::Incompatible | LinkError::Version(_) | LinkError::BadHello => AbortReason::Incompatible,
                _ => AbortReason::GaveUp,
            };
            if !matches!(e, LinkError::Io(_) | LinkError::PeerAborted(_)) {
                let map_id = self.rx.header.map(|h| h.map_id).or(self.tx.as_ref().map(|t| t.header.map_id));
                let msg = Message::Abort { map_id: map_id.unwrap_or(0), reason };
                let _ = send_msg(io, &msg, self.shape.parity, &mut self.stats);
            }
        }
        r
    }

    fn finished(&self) -> bool {
        self.sent() && self.rx.done
    }

    fn send_ack<IO: Write>(&mut self, io: &mut IO, have: &[u32; STREAM_BUFFER / 32]) -> Result<(), LinkError> {
        let ack = self.rx.ack(have, self.finished());
        send_msg(io, &Message::Ack(ack), self.shape.parity, &mut self.stats)?;
        self.stats.acks_sent += 1;
        self.rx.unacked = 0;
        self.rx.ack_now = false;
        Ok(())
    }

    fn step_inner<IO: Read + Write + ReadReady + WriteReady>(
        &mut self,
        io: &mut IO,
        now: u64,
        buffers: &mut LinkBuffers,
    ) -> Result<Progress, LinkError> {
        let (mut tb, mut rb) = buffers.split();
        if !self.started {
            self.started = true;
            self.last_heard = now;
            self.send_hello(io, now)?;
        }
        // Read everything that is there.
        let mut buf = [0u8; 64];
        while io.read_ready().map_err(io_error)? {
            let n = io.read(&mut buf).map_err(io_error)?;
            if n == 0 {
                break;
            }
            self.stats.bytes_received += n as u64;
            self.last_byte = now;
            for &b in buf.get(..n).unwrap_or(&[]) {
                self.on_byte(b, now, &mut tb, &mut rb)?;
            }
        }
        // Half duplex: a turn whose last frame (the one asking) was lost
        // still gets its answer once the line has been quiet a while.
        let quiet = now.saturating_sub(self.last_byte) >= TURN_QUIET_MS;
        // Our `Hello` again, while the peer's is not heard (ours may have
        // been lost: nothing is sent before both are; on a half-duplex line
        // only robot 0 repeats, when the line is quiet, so that two repeats
        // never collide), or at once when the peer says it has not heard ours.
        let hello_due = self.peer_takes_map.is_none()
            && now.saturating_sub(self.hello_at) >= u64::from(self.config.timeout_ms)
            && (!self.config.half_duplex || (quiet && self.robot_id == 0));
        if self.answer_hello || hello_due {
            self.answer_hello = false;
            self.send_hello(io, now)?;
        }
        if self.config.half_duplex && self.rx.unacked > 0 && quiet {
            self.rx.ack_now = true;
        }
        let acked_now = self.rx.ack_now && self.rx.map.is_some();
        if acked_now {
            self.send_ack(io, rb.have)?;
        }
        // Our map goes out now, or (half duplex, not robot 0) once the peer's
        // is in.
        // A data frame only when the line takes it at once: acknowledgements
        // never wait behind a queue of data.
        let may_send = (!self.config.half_duplex || self.robot_id == 0 || self.rx.done)
            && self.peer_takes_map == Some(true)
            && io.write_ready().map_err(io_error)?;
        if let (Some(tx), true) = (self.tx.as_mut(), may_send) {
            let heard = self.last_byte.max(self.last_heard);
            tx.send_next(&mut tb, io, (now, heard), self.shape, &self.config, &mut self.stats)?;
        }
        if self.finished() {
            if self.finished_at.is_none() {
                // Say so twice: the peer may be waiting for exactly this (on
                // a half-duplex line once, and not after an ack of this step:
                // the peer answers the first at once, into the second).
                self.finished_at = Some(now);
                let says = if self.config.half_duplex { usize::from(!acked_now) } else { 2 };
                for _ in 0..says {
                    self.send_ack(io, rb.have)?;
                }
            }
            let lingered = self.finished_at.is_some_and(|t| now >= t + u64::from(self.config.linger_ms));
            if self.peer_finished || lingered {
                return Ok(Progress::Done);
            }
        } else if now.saturating_sub(self.last_heard) > u64::from(self.config.silence_ms) {
            return Err(LinkError::Silent);
        }
        Ok(Progress::Busy)
    }

    /// Sends our `Hello`: who we are, what we take of the peer's map, and
    /// whether we heard the peer's. Well protected: the first frame the
    /// peer judges the line by.
    fn send_hello<IO: Write>(&mut self, io: &mut IO, now: u64) -> Result<(), LinkError> {
        let hello = Hello {
            robot_id: self.robot_id,
            class_table: CLASS_TABLE_VERSION,
            resolution: self.resolution,
            max_payload: MAX_PAYLOAD as u16,
            takes_map: self.rx.map.is_some(),
            capacity: self.rx.map.as_ref().map_or(0, |m| m.capacity().min(u32::MAX as usize) as u32),
            heard: self.peer_takes_map.is_some(),
        };
        self.hello_at = now;
        send_msg(io, &Message::Hello(hello), HELLO_PARITY, &mut self.stats).map(|_| ())
    }

    fn on_byte(&mut self, b: u8, now: u64, tb: &mut TxBufs<'_>, rb: &mut RxBufs<'_>) -> Result<(), LinkError> {
        let Exchange {
            deframer,
            rx,
            tx,
            stats,
            config,
            resolution,
            last_heard,
            peer_finished,
            peer_takes_map,
            peer_id,
            answer_hello,
            line,
            shape,
            ..
        } = self;
        let Some((payload, repaired, in_block)) = take_frame(deframer, line, stats, config, shape, b) else {
            return Ok(());
        };
        let Some(msg) = decode_frame(payload, repaired, stats)? else { return Ok(()) };
        stats.repaired_frames += u32::from(repaired);
        stats.frames_received += 1;
        *last_heard = now;
        match msg {
            Message::Hello(h) => {
                if !compatible(h.class_table, h.resolution, *resolution) {
                    return Err(LinkError::Incompatible);
                }
                if peer_takes_map.is_none() {
                    // First heard: our map cut to what the peer holds,
                    // before anything of it goes out.
                    if let Some(t) = tx.take() {
                        *tx = Some(t.fit(h.capacity, tb.model, config)?);
                    }
                }
                *peer_takes_map = Some(h.takes_map);
                *peer_id = Some(h.robot_id);
                // A peer that has not heard ours gets it (again).
                *answer_hello |= !h.heard;
            }
            Message::Data { offset, poll, tag, data } => {
                rx.echo = tag;
                // Half duplex: an answer only when asked (the turn is over).
                // Blocks carry up to 300 data bytes each: acknowledged every
                // two (every four, the sender's window filled before the
                // acks came: 5% took 1.96 s instead of 1.86, simulated).
                let every = match (config.half_duplex, in_block) {
                    (true, _) => u8::MAX,
                    (false, true) => 2,
                    (false, false) => ACK_EVERY,
                };
                rx.on_data(rb, (offset, poll, every), data, *resolution, stats)?
            }
            Message::Ack(ack) => {
                if ack.flags & ACK_FINISHED != 0 {
                    *peer_finished = true;
                }
                if let Some(t) = tx.as_mut() {
                    t.on_ack(tb.segs, &ack, now, config);
                }
            }
            Message::Abort { map_id, reason } => {
                let ours = tx.as_ref().is_some_and(|t| t.header.map_id == map_id);
                let theirs = rx.header.is_none_or(|h| h.map_id == map_id);
                if ours || theirs {
                    return Err(LinkError::PeerAborted(reason));
                }
            }
        }
        Ok(())
    }
}

/// One byte into the deframer, and what it told of the line (the line
/// estimate and the frame shape follow it): the frame it completed, if
/// any, as (payload, repaired, came in a block).
fn take_frame<'d>(
    deframer: &'d mut BlockDeframer,
    line: &mut LineEstimate,
    stats: &mut LinkStats,
    config: &LinkConfig,
    shape: &mut FrameShape,
    b: u8,
) -> Option<(&'d [u8], bool, bool)> {
    if b != 0 {
        line.byte();
    }
    let (pushed, pieces) = deframer.push(b);
    // No header read: a frame with two of its first bytes hit, or a
    // segment of a block whose descriptors were both lost (its bytes no
    // frame's, and its errors unknown). Half duplex has no blocks, and
    // there it is a frame a collision garbled.
    line.judge(pieces, &pushed, config.half_duplex);
    let taken = match pushed {
        Ok(Some(f)) => {
            stats.count_repairs(f.damage);
            Some((f.payload, f.repaired, f.segments > 0))
        }
        Ok(None) if pieces.is_empty() => return None,
        Ok(None) => None,
        Err(_) => {
            stats.bad_frames += 1;
            None
        }
    };
    *shape = FrameShape::for_line(line.model(), config);
    taken
}

/// A frame's message: `None` (counted as a bad frame) when it does not
/// decode; an error when an intact frame (its CRC-32 holds, nothing
/// repaired) is in another version or a Hello with a non-finite field:
/// the peer, not the line, says so, and waiting would only end at the
/// deadline.
fn decode_frame<'p>(
    payload: &'p [u8],
    repaired: bool,
    stats: &mut LinkStats,
) -> Result<Option<Message<'p>>, LinkError> {
    match Message::decode(payload) {
        Ok(msg) => Ok(Some(msg)),
        Err(MessageError::Version(v)) if !repaired => Err(LinkError::Version(v)),
        Err(MessageError::NonFinite) if !repaired => Err(LinkError::BadHello),
        Err(_) => {
            stats.bad_frames += 1;
            Ok(None)
        }
    }
}
