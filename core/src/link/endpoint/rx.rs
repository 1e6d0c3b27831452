//! The receiving half of an endpoint: stream bytes into a ring, records
//! into the map, acknowledgements.

use super::*;

/// The receiving half: stream bytes into a ring until the records before
/// the first gap are whole, then records into the map.
pub(super) struct Rx<'a, S: VoxelSink> {
    /// `None`: this endpoint receives nothing.
    pub(super) map: Option<&'a mut S>,
    /// Everything before `cum` arrived; before `consumed` was decoded;
    /// `highest` is one past the last byte that arrived.
    pub(super) cum: u32,
    pub(super) consumed: u32,
    pub(super) highest: u32,
    pub(super) header: Option<MapHeader>,
    /// Decodes the map once its header arrived.
    pub(super) decoder: Option<MapDecoder>,
    pub(super) done: bool,
    /// Last stream byte that arrived new.
    pub(super) latest: u32,
    /// Data frames since the last acknowledgement.
    pub(super) unacked: u8,
    pub(super) ack_now: bool,
    /// Tag of the last data frame that arrived (echoed by our acks).
    pub(super) echo: u8,
}

impl<'a, S: VoxelSink> Rx<'a, S> {
    /// The receiving half: into `map` (`None`: receives nothing).
    pub(super) fn new(map: Option<&'a mut S>) -> Self {
        let done = map.is_none();
        Rx {
            map,
            cum: 0,
            consumed: 0,
            highest: 0,
            header: None,
            decoder: None,
            done,
            latest: 0,
            unacked: 0,
            ack_now: false,
            echo: 0,
        }
    }
}

/// Whether stream byte `pos` is held.
fn bit(have: &[u32; STREAM_BUFFER / 32], pos: u32) -> bool {
    let p = pos as usize % STREAM_BUFFER;
    have.get(p / 32).is_some_and(|w| w & (1 << (p % 32)) != 0)
}

fn set_bit(have: &mut [u32; STREAM_BUFFER / 32], pos: u32, on: bool) {
    let p = pos as usize % STREAM_BUFFER;
    if let Some(w) = have.get_mut(p / 32) {
        if on {
            *w |= 1 << (p % 32);
        } else {
            *w &= !(1 << (p % 32));
        }
    }
}

impl<S: VoxelSink> Rx<'_, S> {
    pub(super) fn on_data(
        &mut self,
        b: &mut RxBufs<'_>,
        (offset, poll, ack_every): (u16, bool, u8),
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
        for (k, &byte) in data.iter().enumerate() {
            let pos = start + k as i64;
            if pos < i64::from(self.cum) || pos < 0 {
                continue;
            }
            if pos >= limit {
                break;
            }
            let pos = pos as u32;
            fresh |= !bit(b.have, pos);
            b.ring[pos as usize % STREAM_BUFFER] = byte;
            set_bit(b.have, pos, true);
            self.latest = pos;
        }
        let end = (start + data.len() as i64).clamp(0, limit) as u32;
        if !fresh {
            stats.duplicates += 1;
        }
        self.highest = self.highest.max(end);
        while i64::from(self.cum) < limit && bit(b.have, self.cum) {
            self.cum += 1;
        }
        self.unacked = self.unacked.saturating_add(1);
        if poll || self.unacked >= ack_every {
            self.ack_now = true;
        }
        self.take_records(b, resolution, stats)
    }

    /// Decodes every whole record before the first gap.
    pub(super) fn take_records(
        &mut self,
        b: &mut RxBufs<'_>,
        resolution: f32,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        while self.cum > self.consumed && !self.done {
            let len = usize::from(b.ring[self.consumed as usize % STREAM_BUFFER]);
            if len == 0 {
                return Err(LinkError::Decode(DecodeError::Empty));
            }
            if ((self.cum - self.consumed) as usize) < 1 + len {
                return Ok(());
            }
            let mut rec = [0u8; MAX_RECORD];
            for (k, r) in rec.iter_mut().take(len).enumerate() {
                *r = b.ring[(self.consumed as usize + 1 + k) % STREAM_BUFFER];
            }
            for k in 0..=len as u32 {
                set_bit(b.have, self.consumed + k, false);
            }
            self.consumed += 1 + len as u32;
            self.record(b.model, rec.get(..len).unwrap_or(&[]), resolution, stats)?;
        }
        Ok(())
    }

    pub(super) fn record(
        &mut self,
        model: &mut CodecModel,
        rec: &[u8],
        resolution: f32,
        stats: &mut LinkStats,
    ) -> Result<(), LinkError> {
        let Some(map) = self.map.as_mut() else { return Ok(()) };
        match (self.header, self.decoder.as_mut()) {
            (None, _) => {
                let h = MapHeader::decode(rec).map_err(|_| LinkError::Decode(DecodeError::Truncated))?;
                if !super::compatible(h.class_table, h.resolution, resolution) {
                    return Err(LinkError::Incompatible);
                }
                if h.voxel_count as usize > map.capacity() {
                    return Err(LinkError::TooLarge { voxels: h.voxel_count });
                }
                map.clear();
                self.header = Some(h);
                self.decoder = Some(MapDecoder::new(h.voxel_count as usize, model));
            }
            (Some(_), Some(dec)) => {
                let n = dec.decode_chunk(model, rec, map).map_err(LinkError::Decode)?;
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
    pub(super) fn ack(&self, have: &[u32; STREAM_BUFFER / 32], finished: bool) -> Ack {
        let mut ack = Ack { cum: self.cum as u16, echo: self.echo, ..Ack::default() };
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
            if !bit(have, pos) {
                pos += 1;
                continue;
            }
            let from = pos;
            while pos < self.highest && bit(have, pos) {
                pos += 1;
            }
            runs[found] = (from, pos);
            found += 1;
        }
        if found > MAX_SACK {
            let latest = self.latest.max(self.cum);
            let (mut from, mut to) = (latest, latest);
            while from > self.cum && bit(have, from - 1) {
                from -= 1;
            }
            while to < self.highest && bit(have, to) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::map;

    /// A sender that ignores the capacity our `Hello` said (senders cut
    /// their map to it) is still refused at its header, before a voxel.
    #[test]
    fn a_header_beyond_what_we_hold_is_refused() {
        let mut tiny = map(10);
        let mut rx = Rx::new(Some(&mut tiny));
        let header = MapHeader {
            map_id: 1,
            robot_id: 0,
            class_table: CLASS_TABLE_VERSION,
            anchor_time_us: 0,
            voxel_count: 11,
            resolution: 0.2,
            bounds: [0.0; 6],
            digest: 0,
        };
        let mut rec = [0u8; 64];
        let n = header.encode(&mut rec).unwrap();
        let (mut model, mut stats) = (CodecModel::new(), LinkStats::default());
        let r = rx.record(&mut model, &rec[..n], 0.2, &mut stats);
        assert_eq!(r, Err(LinkError::TooLarge { voxels: 11 }));
        let fits = MapHeader { voxel_count: 10, ..header };
        let n = fits.encode(&mut rec).unwrap();
        assert_eq!(rx.record(&mut model, &rec[..n], 0.2, &mut stats), Ok(()));
    }
}
