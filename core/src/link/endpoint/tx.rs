//! The sending half of an endpoint: the map as a stream of records, a
//! window of segments in flight, retransmission by selective repeat.

use super::*;

/// Transmissions whose send times are kept (for round trips from echoes).
pub(super) const SENT_TIMES: usize = 32;

/// One frame's worth of the stream in flight.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub(super) struct Segment {
    pub(super) start: u32,
    pub(super) len: u16,
    pub(super) sends: u8,
    /// Known lost (1): waits for retransmission.
    pub(super) lost: u8,
    /// Transmission number of its last send (its tag is this modulo 256;
    /// the peer having read a later one while this one is not held means
    /// this one was lost: the line keeps order).
    pub(super) order: u32,
    /// Milliseconds (wrapping) of its last send.
    pub(super) sent_at: u32,
}

/// The frames in flight, oldest first: a list of fixed capacity in plain
/// integers (part of [`LinkBuffers`]).
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub(crate) struct SegList {
    len: u32,
    items: [Segment; MAX_SEGMENTS],
}

impl SegList {
    pub(super) const fn new() -> Self {
        const EMPTY: Segment = Segment { start: 0, len: 0, sends: 0, lost: 0, order: 0, sent_at: 0 };
        SegList { len: 0, items: [EMPTY; MAX_SEGMENTS] }
    }

    fn live(&self) -> &[Segment] {
        self.items.get(..self.len as usize).unwrap_or(&[])
    }

    fn live_mut(&mut self) -> &mut [Segment] {
        self.items.get_mut(..self.len as usize).unwrap_or(&mut [])
    }

    pub(super) fn len(&self) -> usize {
        self.live().len()
    }

    pub(super) fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn is_full(&self) -> bool {
        self.len() >= MAX_SEGMENTS
    }

    pub(super) fn clear(&mut self) {
        self.len = 0;
    }

    fn get(&self, i: usize) -> Option<&Segment> {
        self.live().get(i)
    }

    fn get_mut(&mut self, i: usize) -> Option<&mut Segment> {
        self.live_mut().get_mut(i)
    }

    fn iter(&self) -> core::slice::Iter<'_, Segment> {
        self.live().iter()
    }

    fn iter_mut(&mut self) -> core::slice::IterMut<'_, Segment> {
        self.live_mut().iter_mut()
    }

    /// Appends `s`; `Err` when full.
    fn push(&mut self, s: Segment) -> Result<(), ()> {
        self.insert(self.len(), s)
    }

    /// Puts `s` at `i`, the later ones one on; `Err` when full or `i` is
    /// past the end.
    fn insert(&mut self, i: usize, s: Segment) -> Result<(), ()> {
        let n = self.len();
        if n >= MAX_SEGMENTS || i > n {
            return Err(());
        }
        let tail = self.items.get_mut(i..=n).ok_or(())?;
        tail.rotate_right(1);
        *tail.first_mut().ok_or(())? = s;
        self.len += 1;
        Ok(())
    }

    /// Takes out the segment at `i`, the later ones one back.
    fn remove(&mut self, i: usize) {
        if let Some(tail) = self.live_mut().get_mut(i..) {
            tail.rotate_left(1);
            self.len -= 1;
        }
    }
}

/// The sending half: the map as a stream of records (header, then codec
/// chunks), kept from the first unacknowledged byte on.
pub(super) struct Tx<'a, S: VoxelStorage, O: Borrow<LocalMap<S>>> {
    pub(super) encoder: MapEncoder<'a, S, O>,
    pub(super) header: MapHeader,
    pub(super) header_queued: bool,
    /// Stream offsets: everything before `acked` is held by the receiver,
    /// before `sent_end` was sent at least once, before `produced` encoded.
    pub(super) acked: u32,
    pub(super) sent_end: u32,
    pub(super) produced: u32,
    /// Data frames sent (the last one's transmission number).
    pub(super) order: u32,
    /// The last transmission the peer read, as its acks echo it: frames
    /// sent after it are unread (in its queue, on the line, or lost).
    pub(super) acked_order: u32,
    /// When the last [`SENT_TIMES`] transmissions left (ms, wrapping), by
    /// transmission number: an echo gives the round trip of the very copy
    /// the peer read, resent or not.
    pub(super) sent_times: [u32; SENT_TIMES],
    /// The receiver said it holds the whole map.
    pub(super) complete: bool,
    /// Data bytes per frame, from the estimated line.
    pub(super) size: usize,
    /// Parity bytes per frame, from the estimated line.
    pub(super) parity: usize,
    /// Data goes in blocks of this shape (a line that drops and duplicates
    /// bytes often), else in frames.
    pub(super) block: Option<crate::wire::BlockShape>,
    pub(super) srtt: Option<u32>,
    /// Mean deviation of the round trips from `srtt` (ms).
    pub(super) rttvar: u32,
    /// Timeouts in a row with no progress at all.
    pub(super) backoff: u32,
    /// When an acknowledgement last took bytes off our hands.
    pub(super) last_progress: u64,
    /// When the stalled line was last probed.
    pub(super) last_probe: u64,
    /// Resends while nothing new can go (every fourth asks for an answer).
    pub(super) idle_resends: u32,
    /// Rounds of such resends (the oldest bytes sent again) since the peer
    /// last read a frame of ours: on a clean line each doubles the wait
    /// before the next.
    pub(super) unanswered: u32,
    /// Half duplex: when the frame that ended our turn went out (it asked
    /// for an answer; anything sent before the answer would collide with it).
    pub(super) awaiting: Option<u64>,
    /// Half duplex: bytes sent in the current turn (a burst of frames, the
    /// last asking for an answer).
    pub(super) burst: u32,
    /// Half duplex: smoothed time from the end of a turn to the answer (ms).
    pub(super) answer_ms: Option<u32>,
}

impl<'a, S: VoxelStorage, O: Borrow<LocalMap<S>>> Tx<'a, S, O> {
    /// The sending half of transfer `map_id` of robot `robot_id`'s `map`
    /// (anchored at `anchor_time_us`), its Morton order prepared in
    /// `scratch`, coding with `model` (reset).
    pub(super) fn new(
        map: O,
        scratch: &'a mut [u32],
        model: &mut CodecModel,
        (map_id, robot_id, anchor_time_us): (u32, u8, u64),
        config: &LinkConfig,
    ) -> Result<Self, LinkError> {
        let encoder = MapEncoder::new(map, scratch, model).map_err(|_| LinkError::Setup)?;
        let header = MapHeader {
            map_id,
            robot_id,
            class_table: CLASS_TABLE_VERSION,
            anchor_time_us,
            voxel_count: 0,
            resolution: 0.0,
            bounds: [0.0; 6],
            digest: 0,
        };
        Ok(Self::start(encoder, header, config))
    }

    /// The same transfer with only what a peer holding `capacity` voxels
    /// can take: the voxels nearest where the map keeps them
    /// ([`LocalMap::keep_centre`]), as many as fit ([`LocalMap::nearest`]).
    /// Unchanged when the map fits.
    /// Only before anything went out.
    pub(super) fn fit(self, capacity: u32, model: &mut CodecModel, config: &LinkConfig) -> Result<Self, LinkError> {
        if self.header.voxel_count <= capacity || self.header_queued || self.produced > 0 {
            return Ok(self);
        }
        let header = self.header;
        let (map, scratch) = self.encoder.into_parts();
        let m: &LocalMap<S> = map.borrow();
        let n = m.nearest(m.keep_centre(), capacity as usize, scratch);
        let encoder = MapEncoder::subset(map, scratch, n, model).map_err(|_| LinkError::Setup)?;
        Ok(Self::start(encoder, header, config))
    }

    /// A transfer of what `encoder` streams, announced by `header` (its
    /// count, voxel size, bounds and digest taken from what is streamed).
    fn start(encoder: MapEncoder<'a, S, O>, mut header: MapHeader, config: &LinkConfig) -> Self {
        let m: &LocalMap<S> = encoder.map();
        let keys = encoder.order().iter().filter_map(|&i| m.voxel(i as usize)).map(|v| v.key);
        let bounds = VoxelKey::bounds(keys, m.resolution());
        header.bounds = bounds.map(|(lo, hi)| [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]]).unwrap_or([0.0; 6]);
        header.voxel_count = encoder.count() as u32;
        header.resolution = m.resolution();
        header.digest = encoder.digest();
        let initial = FrameShape::initial(config);
        Tx {
            encoder,
            header,
            header_queued: false,
            acked: 0,
            sent_end: 0,
            produced: 0,
            order: 0,
            acked_order: 0,
            sent_times: [0; SENT_TIMES],
            complete: false,
            size: initial.chunk,
            parity: initial.parity,
            block: None,
            srtt: None,
            rttvar: 0,
            backoff: 0,
            last_progress: 0,
            last_probe: 0,
            idle_resends: 0,
            unanswered: 0,
            awaiting: None,
            burst: 0,
            answer_ms: None,
        }
    }
}

impl<S: VoxelStorage, O: Borrow<LocalMap<S>>> Tx<'_, S, O> {
    /// Encodes records into the buffer while a whole record fits.
    pub(super) fn fill(&mut self, b: &mut TxBufs<'_>) -> Result<(), LinkError> {
        loop {
            if STREAM_BUFFER - (self.produced.wrapping_sub(self.acked) as usize) < MAX_RECORD {
                return Ok(());
            }
            let mut rec = [0u8; MAX_RECORD];
            let body = rec.get_mut(1..).ok_or(LinkError::Setup)?;
            let n = if !self.header_queued {
                self.header_queued = true;
                self.header.encode(body).map_err(|_| LinkError::Setup)?
            } else if self.encoder.is_done() {
                return Ok(());
            } else {
                let chunk = body.get_mut(..RECORD_CHUNK).ok_or(LinkError::Setup)?;
                self.encoder.next_chunk(b.model, chunk).map_err(|_| LinkError::Setup)?
            };
            rec[0] = u8::try_from(n).map_err(|_| LinkError::Setup)?;
            for &byte in rec.get(..=n).ok_or(LinkError::Setup)? {
                b.ring[self.produced as usize % STREAM_BUFFER] = byte;
                self.produced = self.produced.wrapping_add(1);
            }
        }
    }

    pub(super) fn exhausted(&self) -> bool {
        self.header_queued && self.encoder.is_done()
    }

    /// Bytes allowed in flight: 1 KiB until something came back (frames
    /// sized before the line was known may all be lost, and must not fill
    /// the window), then all the receiver can hold.
    pub(super) fn window(&self) -> u32 {
        if self.srtt.is_some() {
            WINDOW
        } else {
            1024
        }
    }

    pub(super) fn can_send_new(&self, segs: &SegList, config: &LinkConfig) -> bool {
        self.sent_end != self.produced
            && self.sent_end.wrapping_sub(self.acked) < self.window()
            && segs.len() + CUT_RESERVE < MAX_SEGMENTS
            && (!config.half_duplex || self.burst < BURST)
    }

    /// How long bytes may go unacknowledged before they are sent again:
    /// twice the smoothed round trip (before any, `timeout_ms`).
    /// Capped at `max_timeout_ms`, but never below a round trip as the
    /// peer answers now (a slow peer's queue lengthens it: resending
    /// sooner than the answer can come is a storm, not a repair).
    pub(super) fn rto(&self, config: &LinkConfig) -> u32 {
        match self.srtt {
            Some(s) => (2 * s + 20).max(30).min(config.max_timeout_ms.max(s + 4 * self.rttvar + 20)),
            None => config.timeout_ms.min(config.max_timeout_ms),
        }
    }

    /// Cuts segment `i` to the current frame size; the rest stays lost.
    pub(super) fn cut(&mut self, segs: &mut SegList, i: usize) {
        let Some(s) = segs.get(i).copied() else { return };
        if usize::from(s.len) <= self.size || segs.is_full() {
            return;
        }
        let keep = self.size as u16;
        let rest = Segment { start: s.start.wrapping_add(u32::from(keep)), len: s.len - keep, ..s };
        if segs.insert(i + 1, rest).is_ok() {
            if let Some(first) = segs.get_mut(i) {
                first.len = keep;
            }
        }
    }

    pub(super) fn transmit<IO: Write>(
        &mut self,
        b: &mut TxBufs<'_>,
        i: usize,
        poll: bool,
        io: &mut IO,
        now: u64,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        let seg = b.segs.get_mut(i).ok_or(LinkError::Setup)?;
        let mut data = [0u8; MAX_PAYLOAD];
        let len = usize::from(seg.len);
        for (k, d) in data.iter_mut().take(len).enumerate() {
            *d = b.ring[seg.start.wrapping_add(k as u32) as usize % STREAM_BUFFER];
        }
        self.order += 1;
        if let Some(t) = self.sent_times.get_mut(self.order as usize % SENT_TIMES) {
            *t = now as u32;
        }
        seg.order = self.order;
        seg.sends = seg.sends.saturating_add(1);
        seg.sent_at = now as u32;
        seg.lost = 0;
        self.burst = self.burst.saturating_add(len as u32);
        if poll {
            self.awaiting = Some(now);
        }
        let offset = (seg.start % OFFSET_MODULUS) as u16;
        let msg = Message::Data { offset, poll, tag: self.order as u8, data: data.get(..len).unwrap_or(&[]) };
        match self.block {
            Some(block) => send_block(io, &msg, (block, self.parity), stats)?,
            None => send_msg(io, &msg, self.parity, stats)?,
        };
        stats.frame_shape = (len as u16, self.block.map_or(self.parity, |b| b.parity) as u8);
        Ok(())
    }

    /// Sends at most one data frame: a lost one first (cut to the current
    /// size), else new bytes, else bytes unacknowledged for a while again.
    /// The last uses a line that would idle: the oldest bytes hold the
    /// window, so on a bad line they go out again and again until one copy
    /// gets through. When not a byte came from the peer (`heard`, of
    /// `(now, heard)`) for four timeouts the line may be down: then only
    /// the oldest bytes, at a timeout that doubles.
    pub(super) fn send_next<IO: Write>(
        &mut self,
        b: &mut TxBufs<'_>,
        io: &mut IO,
        (now, heard): (u64, u64),
        shape: FrameShape,
        config: &LinkConfig,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        if self.complete {
            return Ok(());
        }
        // Half duplex: the answer to our turn comes within about twice the
        // usual delay, else the turn is taken again.
        let answer = self.answer_ms.map_or(self.rto(config), |a| (2 * a + 20).min(self.rto(config)));
        if config.half_duplex && self.awaiting.is_some_and(|t| now < t + u64::from(answer)) {
            return Ok(());
        }
        self.fill(b)?;
        // Frames sized for the line as the peer's frames show it (after a
        // stall, no larger than the probes were).
        let probe = self.size;
        (self.size, self.parity, self.block) = (shape.chunk, shape.parity, shape.block);
        if self.backoff > 0 {
            self.size = self.size.min(probe);
        }
        let rto = self.rto(config);
        if self.unread() >= self.unread_limit() && !b.segs.is_empty() {
            // The peer has not read what it was sent: a peer busy elsewhere
            // or on a slow host, whose queue more frames would only
            // lengthen (a storm of resends it reads much later). Wait for
            // its acks; without progress for a timeout (all lost, or the
            // peer busy), probe at a timeout that doubles.
            return match now >= self.last_progress + u64::from(rto) {
                true => self.probe_when_due(b, io, now, shape, config, stats),
                false => Ok(()),
            };
        }
        if let Some(i) = b.segs.iter().position(|s| s.lost != 0) {
            return self.resend_lost(b, i, io, now, config, stats);
        }
        if self.can_send_new(b.segs, config) {
            return self.send_new(b, io, now, config, stats);
        }
        if b.segs.is_empty() {
            return Ok(());
        }
        if now >= self.last_progress.max(heard) + 4 * u64::from(rto) {
            return self.probe_when_due(b, io, now, shape, config, stats);
        }
        self.resend_unacknowledged(b, io, now, (shape, rto), config, stats)
    }

    /// Sends segment `i`, reported lost, again (cut to the current size).
    fn resend_lost<IO: Write>(
        &mut self,
        b: &mut TxBufs<'_>,
        i: usize,
        io: &mut IO,
        now: u64,
        config: &LinkConfig,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        self.cut(b.segs, i);
        let more = b.segs.iter().skip(i + 1).any(|s| s.lost != 0);
        let len = b.segs.get(i).map_or(0, |s| u32::from(s.len));
        let turn_over = config.half_duplex && self.burst.saturating_add(len) >= BURST;
        let poll = turn_over || (!more && !self.can_send_new(b.segs, config));
        // One copy: since the deframer repairs single errors, extra
        // copies of bytes lost again and again no longer paid (measured).
        stats.retransmissions += 1;
        self.transmit(b, i, poll, io, now, stats)
    }

    /// Sends again the oldest bytes not acknowledged for a while (a
    /// timeout `rto` on a clean line, sooner on a lossy one), if any are.
    fn resend_unacknowledged<IO: Write>(
        &mut self,
        b: &mut TxBufs<'_>,
        io: &mut IO,
        now: u64,
        (shape, rto): (FrameShape, u32),
        config: &LinkConfig,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        // On a clean line, bytes not acknowledged in a timeout; on a lossy
        // one, sooner (a round trip and a half): there the oldest bytes are
        // likely lost again, and the line would idle meanwhile.
        // Sooner, but not sooner than round trips that vary allow.
        let wait = match self.srtt {
            Some(s) if shape.arrival < 0.995 && shape.block.is_none() => {
                (s + (s / 2).max(4 * self.rttvar) + 5).min(rto)
            }
            _ => rto,
        };
        // On a clean line (also before anything arrived), only the
        // oldest bytes go again, asking for an answer (which tells what is
        // missing), and rounds that brought none double the wait: the peer
        // reads late (busy, or on a slow host) and reads every copy in the
        // end. On a lossy line the copies are likely lost: the oldest eight
        // may go, at the same pace (doubling there made 20% take 20 s
        // instead of 12, simulated).
        let clean = shape.clean;
        let (doubling, oldest) = if clean { (self.unanswered.min(5), 1) } else { (0, 8) };
        let wait = wait.saturating_mul(1 << doubling);
        let due = b.segs.iter().take(oldest).position(|s| (now as u32).wrapping_sub(s.sent_at) >= wait);
        if let Some(i) = due {
            self.idle_resends += 1;
            if i == 0 {
                self.unanswered += 1;
            }
            self.cut(b.segs, i);
            stats.retransmissions += 1;
            let poll = config.half_duplex || clean || self.idle_resends.is_multiple_of(4);
            return self.transmit(b, i, poll, io, now, stats);
        }
        Ok(())
    }

    /// Sends the next new bytes of the stream in a frame of its own.
    fn send_new<IO: Write>(
        &mut self,
        b: &mut TxBufs<'_>,
        io: &mut IO,
        now: u64,
        config: &LinkConfig,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        let room = self.window().saturating_sub(self.sent_end.wrapping_sub(self.acked)) as usize;
        let len = self.size.min(self.produced.wrapping_sub(self.sent_end) as usize).min(room);
        let seg = Segment { start: self.sent_end, len: len as u16, sends: 0, lost: 0, order: 0, sent_at: now as u32 };
        if b.segs.is_empty() {
            // The timers start with the first bytes in flight.
            self.last_progress = now;
        }
        b.segs.push(seg).map_err(|_| LinkError::Setup)?;
        self.sent_end = self.sent_end.wrapping_add(len as u32);
        self.fill(b)?;
        stats.chunk_bytes_sent += len as u64;
        let poll = !self.can_send_new(b.segs, config);
        self.transmit(b, b.segs.len() - 1, poll, io, now, stats)
    }

    /// Data frames sent that the peer has not read, as far as its acks tell.
    pub(super) fn unread(&self) -> u32 {
        self.order.wrapping_sub(self.acked_order)
    }

    /// Most unread frames before the sender waits: two windows of frames
    /// of the current size, at least 8 and at most 128 (so that a tag, the
    /// transmission number modulo 256, names one frame unread; probes add
    /// one each, at a timeout that doubles).
    fn unread_limit(&self) -> u32 {
        (2 * WINDOW / self.size.max(1) as u32).clamp(8, 128)
    }

    /// A probe once the doubling timeout since the last one has run.
    fn probe_when_due<IO: Write>(
        &mut self,
        b: &mut TxBufs<'_>,
        io: &mut IO,
        now: u64,
        shape: FrameShape,
        config: &LinkConfig,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        let rto = self.rto(config);
        let wait = u64::from(rto.saturating_mul(1 << self.backoff.min(8)).min(config.max_timeout_ms.max(rto)));
        if now < self.last_probe + wait {
            return Ok(());
        }
        self.probe(b, io, now, shape, config, stats)
    }

    /// Nothing heard: the line may have got worse. Resends the oldest bytes
    /// sized for what the frames that do arrive say, and at most half the
    /// last size, asking for an answer; gives up after `max_retries`.
    fn probe<IO: Write>(
        &mut self,
        b: &mut TxBufs<'_>,
        io: &mut IO,
        now: u64,
        shape: FrameShape,
        config: &LinkConfig,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        if self.backoff >= u32::from(config.max_retries) {
            return Err(LinkError::GaveUp { seq: self.acked });
        }
        self.backoff += 1;
        self.last_probe = now;
        let half = (self.size / 2).max(usize::from(config.min_chunk));
        (self.size, self.parity, self.block) = (shape.chunk.min(half), shape.parity, shape.block);
        self.cut(b.segs, 0);
        stats.retransmissions += 1;
        self.transmit(b, 0, true, io, now, stats)
    }

    /// Takes an acknowledgement: drops what it covers, marks lost what was
    /// sent before something it covers, measures the round trip.
    pub(super) fn on_ack(&mut self, segs: &mut SegList, ack: &Ack, now: u64, config: &LinkConfig) {
        let ahead = ack.cum.wrapping_sub(self.acked as u16) as u32;
        if ahead > self.sent_end.wrapping_sub(self.acked) {
            return; // stale or foreign
        }
        let cum = self.acked.wrapping_add(ahead);
        let mut ranges = [(0u32, 0u32); MAX_SACK];
        for (r, b) in ranges.iter_mut().zip(ack.blocks()) {
            let from = cum.wrapping_add(u32::from(b.start));
            *r = (from, from.wrapping_add(u32::from(b.len)));
        }
        let held = |s: &Segment| {
            let end = s.start.wrapping_add(u32::from(s.len));
            end.wrapping_sub(self.acked) <= ahead
                || ranges
                    .iter()
                    .any(|&(a, b)| b != a && s.start.wrapping_sub(a) < 1 << 30 && b.wrapping_sub(end) < 1 << 30)
        };
        if let Some(t) = self.awaiting {
            let sample = (now.saturating_sub(t) as u32).min(config.max_timeout_ms);
            self.answer_ms = Some(self.answer_ms.map_or(sample, |a| (7 * a + sample) / 8));
        }
        (self.awaiting, self.burst) = (None, 0);
        let mut progress = ahead > 0;
        // The peer read everything up to the frame it echoes: its tag is
        // that frame's transmission number modulo 256, and fewer than 256
        // are ever unread (see `unread_limit`). An older ack says less.
        let back = (self.order as u8).wrapping_sub(ack.echo);
        let read = self.order.wrapping_sub(u32::from(back));
        let newer = read.wrapping_sub(self.acked_order) < 1 << 31;
        if newer {
            progress |= read != self.acked_order;
            self.acked_order = read;
        }
        let mut i = 0;
        while let Some(s) = segs.get(i).copied() {
            if held(&s) {
                segs.remove(i);
                progress = true;
            } else {
                i += 1;
            }
        }
        // The round trip of the very copy the peer read last: the ack
        // left as it read that frame (nothing later of ours had reached it).
        let recent = self.order.wrapping_sub(read) < SENT_TIMES as u32 && read != 0;
        if let Some(&sent_at) = self.sent_times.get(read as usize % SENT_TIMES).filter(|_| newer && recent) {
            let sample = (now as u32).wrapping_sub(sent_at);
            if let Some(r) = self.srtt {
                self.rttvar = (3 * self.rttvar + r.abs_diff(sample)) / 4;
            }
            self.srtt = Some(self.srtt.map_or(sample, |r| (7 * r + sample) / 8));
        }
        self.acked = cum;
        // With all its blocks, the ack describes the whole stream: what it
        // does not hold is missing. Otherwise it describes the stream up to
        // the end of its next-to-last block; beyond, nothing is known.
        let all = ack.flags & ACK_ALL_BLOCKS != 0;
        let known = ranges.get(..usize::from(ack.blocks).saturating_sub(1)).unwrap_or(&[]).last().map_or(cum, |r| r.1);
        for s in segs.iter_mut() {
            let within = all || known.wrapping_sub(s.start.wrapping_add(u32::from(s.len))) < 1 << 30;
            let before = self.acked_order.wrapping_sub(s.order).wrapping_sub(1) < 1 << 31;
            if s.lost == 0 && before && within {
                s.lost = 1;
            }
        }
        if progress {
            self.backoff = 0;
            self.unanswered = 0;
            self.last_progress = now;
        }
        if ack.flags & ACK_COMPLETE != 0 && self.exhausted() && self.acked == self.produced {
            self.complete = true;
            segs.clear();
        }
    }
}
