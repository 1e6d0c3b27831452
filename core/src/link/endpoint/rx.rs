//! The receiving half of an endpoint: stream bytes into a ring, records
//! into the map, acknowledgements.

use super::*;

/// The receiving half: stream bytes into a ring until the records before
/// the first gap are whole, then records into the map.
pub(super) struct Rx<'a, S: VoxelSink> {
    /// `None`: this endpoint receives nothing.
    pub(super) map: Option<&'a mut S>,
    pub(super) ring: &'a mut [u8; STREAM_BUFFER],
    pub(super) have: &'a mut [u32; STREAM_BUFFER / 32],
    /// Everything before `cum` arrived; before `consumed` was decoded;
    /// `highest` is one past the last byte that arrived.
    pub(super) cum: u32,
    pub(super) consumed: u32,
    pub(super) highest: u32,
    pub(super) header: Option<MapHeader>,
    /// The codec's model, until the header names the map; then the decoder's.
    pub(super) model: Option<&'a mut CodecModel>,
    pub(super) decoder: Option<MapDecoder<'a>>,
    pub(super) done: bool,
    /// Last stream byte that arrived new.
    pub(super) latest: u32,
    /// Data frames since the last acknowledgement.
    pub(super) unacked: u8,
    pub(super) ack_now: bool,
}

impl<'a, S: VoxelSink> Rx<'a, S> {
    /// The receiving half: into `map` (`None`: receives nothing), working
    /// in `ring`, `have` and `model`.
    pub(super) fn new(
        map: Option<&'a mut S>,
        ring: &'a mut [u8; STREAM_BUFFER],
        have: &'a mut [u32; STREAM_BUFFER / 32],
        model: &'a mut CodecModel,
    ) -> Self {
        let done = map.is_none();
        Rx {
            map,
            ring,
            have,
            cum: 0,
            consumed: 0,
            highest: 0,
            header: None,
            model: Some(model),
            decoder: None,
            done,
            latest: 0,
            unacked: 0,
            ack_now: false,
        }
    }
}

impl<S: VoxelSink> Rx<'_, S> {
    pub(super) fn bit(&self, pos: u32) -> bool {
        let p = pos as usize % STREAM_BUFFER;
        self.have.get(p / 32).is_some_and(|w| w & (1 << (p % 32)) != 0)
    }

    pub(super) fn set_bit(&mut self, pos: u32, on: bool) {
        let p = pos as usize % STREAM_BUFFER;
        if let Some(w) = self.have.get_mut(p / 32) {
            if on {
                *w |= 1 << (p % 32);
            } else {
                *w &= !(1 << (p % 32));
            }
        }
    }

    pub(super) fn on_data(
        &mut self,
        offset: u16,
        poll: bool,
        data: &[u8],
        resolution: f32,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        if self.map.is_none() {
            return Ok(());
        }
        // The frame's place in the stream, near what we hold.
        let ahead = (u32::from(offset).wrapping_sub(self.cum) % OFFSET_MODULUS) as i64;
        let delta = if ahead >= i64::from(OFFSET_MODULUS / 2) { ahead - i64::from(OFFSET_MODULUS) } else { ahead };
        let start = i64::from(self.cum) + delta;
        let limit = i64::from(self.consumed) + STREAM_BUFFER as i64;
        let mut fresh = false;
        for (k, &b) in data.iter().enumerate() {
            let pos = start + k as i64;
            if pos < i64::from(self.cum) || pos < 0 {
                continue;
            }
            if pos >= limit {
                break;
            }
            let pos = pos as u32;
            fresh |= !self.bit(pos);
            self.ring[pos as usize % STREAM_BUFFER] = b;
            self.set_bit(pos, true);
            self.latest = pos;
        }
        let end = (start + data.len() as i64).clamp(0, limit) as u32;
        if !fresh {
            stats.duplicates += 1;
        }
        self.highest = self.highest.max(end);
        while i64::from(self.cum) < limit && self.bit(self.cum) {
            self.cum += 1;
        }
        self.unacked = self.unacked.saturating_add(1);
        if poll || self.unacked >= ACK_EVERY {
            self.ack_now = true;
        }
        self.take_records(resolution, stats)
    }

    /// Decodes every whole record before the first gap.
    pub(super) fn take_records(&mut self, resolution: f32, stats: &mut LinkStats) -> Result<(), LinkError> {
        while self.cum > self.consumed && !self.done {
            let len = usize::from(self.ring[self.consumed as usize % STREAM_BUFFER]);
            if len == 0 {
                return Err(LinkError::Decode(DecodeError::Empty));
            }
            if ((self.cum - self.consumed) as usize) < 1 + len {
                return Ok(());
            }
            let mut rec = [0u8; MAX_RECORD];
            for (k, r) in rec.iter_mut().take(len).enumerate() {
                *r = self.ring[(self.consumed as usize + 1 + k) % STREAM_BUFFER];
            }
            for k in 0..=len as u32 {
                self.set_bit(self.consumed + k, false);
            }
            self.consumed += 1 + len as u32;
            self.record(rec.get(..len).unwrap_or(&[]), resolution, stats)?;
        }
        Ok(())
    }

    pub(super) fn record(&mut self, rec: &[u8], resolution: f32, stats: &mut LinkStats) -> Result<(), LinkError> {
        let Some(map) = self.map.as_mut() else { return Ok(()) };
        match (self.header, self.decoder.as_mut()) {
            (None, _) => {
                let h = MapHeader::decode(rec).map_err(|_| LinkError::Decode(DecodeError::Truncated))?;
                if h.class_table != CLASS_TABLE_VERSION || (h.resolution - resolution).abs() > 1e-6 * resolution {
                    return Err(LinkError::Incompatible);
                }
                if h.voxel_count as usize > map.capacity() {
                    return Err(LinkError::TooLarge { voxels: h.voxel_count });
                }
                map.clear();
                self.header = Some(h);
                let model = self.model.take().ok_or(LinkError::Setup)?;
                self.decoder = Some(MapDecoder::new(h.voxel_count as usize, model));
            }
            (Some(_), Some(dec)) => {
                let n = dec.decode_chunk(rec, map).map_err(LinkError::Decode)?;
                stats.voxels_received += n as u32;
            }
            (Some(_), None) => return Err(LinkError::Setup),
        }
        if let (Some(h), Some(dec)) = (self.header, self.decoder.as_ref()) {
            if dec.is_complete() {
                if dec.digest() != h.digest {
                    return Err(LinkError::Digest);
                }
                self.done = true;
                self.ack_now = true;
            }
        }
        Ok(())
    }

    /// What we hold, as an acknowledgement.
    pub(super) fn ack(&self, finished: bool) -> Ack {
        let mut ack = Ack { cum: self.cum as u16, ..Ack::default() };
        if self.done {
            ack.flags |= ACK_COMPLETE;
        }
        if finished {
            ack.flags |= ACK_FINISHED;
        }
        // The runs held after `cum`, first ones first; if there are more
        // than fit, the last slot goes to the run that grew last.
        let mut runs = [(0u32, 0u32); MAX_SACK + 1];
        let mut found = 0;
        let mut pos = self.cum;
        while pos < self.highest && found < runs.len() {
            if !self.bit(pos) {
                pos += 1;
                continue;
            }
            let from = pos;
            while pos < self.highest && self.bit(pos) {
                pos += 1;
            }
            runs[found] = (from, pos);
            found += 1;
        }
        if found > MAX_SACK {
            let latest = self.latest.max(self.cum);
            let (mut from, mut to) = (latest, latest);
            while from > self.cum && self.bit(from - 1) {
                from -= 1;
            }
            while to < self.highest && self.bit(to) {
                to += 1;
            }
            if from > runs[MAX_SACK - 2].1 && to > from {
                runs[MAX_SACK - 1] = (from, to);
            }
        } else {
            ack.flags |= ACK_ALL_BLOCKS;
        }
        for &(from, to) in runs.iter().take(found.min(MAX_SACK)) {
            if let Some(slot) = ack.sack.get_mut(usize::from(ack.blocks)) {
                *slot = SackBlock { start: (from - self.cum) as u16, len: (to - from) as u16 };
                ack.blocks += 1;
            }
        }
        ack
    }
}
