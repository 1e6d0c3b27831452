//! A peer's map followed over a broadcast (its map updates on DDS): the
//! updates a robot publishes to every peer at once, none answered
//! ([`cosem_core::session::Publisher::delivered`]), a snapshot every few
//! ([`cosem_core::session::Publisher::snapshot_next`]). Updates and
//! snapshots come on two topics, so out of order: each waits here until
//! the one it applies to is held. A follower that missed one, or joined
//! late, waits for the next snapshot (a late joiner gets the last one and
//! the updates after it from the topics' transient-local history).
//!
//! A restarted peer publishes under a new epoch: its first snapshot whose
//! stamp is newer than anything of the epoch followed replaces the copy;
//! anything older of another epoch is a stale sample of a past run, and
//! dropped.

use crate::maps::mapping::HostMap;
use cosem_core::map::VecStorage;
use cosem_core::session::{Applied, Replica};
use cosem_core::wire::update::UpdateView;

/// Updates held back at most, waiting for the one they apply to.
pub const PENDING_LIMIT: usize = 64;

/// One update waiting.
struct Pending {
    epoch: u16,
    base: u32,
    version: u32,
    /// The sender's stamp (ns).
    stamp: i64,
    bytes: Vec<u8>,
}

/// What a follower did with an update offered.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Offered {
    /// Updates applied (this one and any it let through).
    pub applied: usize,
    /// The copy was replaced by a new epoch's snapshot (the peer
    /// restarted): what was estimated on the old copy is void.
    pub restarted: bool,
    /// Updates that applied and did not come out as the peer's map (the
    /// copy emptied, a snapshot awaited).
    pub diverged: usize,
}

/// The copy of one peer's map, and what waits to be applied to it.
pub struct Follower {
    replica: Replica<VecStorage>,
    epoch: Option<u16>,
    /// The newest stamp of the epoch followed (ns).
    newest: i64,
    pending: Vec<Pending>,
}

impl Follower {
    /// An empty copy over `map` (its voxel size: the peer's; its capacity:
    /// the most the copy can hold).
    pub fn new(map: HostMap) -> Self {
        Follower { replica: Replica::new(map), epoch: None, newest: i64::MIN, pending: Vec::new() }
    }

    /// The copy.
    pub fn map(&self) -> &HostMap {
        self.replica.map()
    }

    /// Where the peer was, as its last update said
    /// ([`Replica::peer_place`]).
    pub fn peer_place(&self) -> Option<[f32; 3]> {
        self.replica.peer_place()
    }

    /// The version held (0: none yet).
    pub fn version(&self) -> u32 {
        self.replica.version()
    }

    /// The epoch followed, once a snapshot was applied.
    pub fn epoch(&self) -> Option<u16> {
        self.epoch
    }

    /// Updates waiting.
    pub fn waiting(&self) -> usize {
        self.pending.len()
    }

    /// Takes an update (`stamp`: its sender's, ns) and applies what can
    /// be; `scratch`: two `u32` a voxel of the copy. An update that does
    /// not parse (length, kind, checksum) or is a stale sample of a past
    /// epoch is an error saying so, and nothing changed.
    pub fn offer(&mut self, stamp: i64, bytes: Vec<u8>, scratch: &mut [u32]) -> Result<Offered, String> {
        let h =
            UpdateView::parse(&bytes).map_err(|e| format!("a malformed map update ({} bytes): {e}", bytes.len()))?;
        let h = h.header;
        if self.epoch.is_some_and(|e| e != h.epoch) && stamp <= self.newest {
            return Err(format!(
                "a map update of epoch {} older than epoch {:?}'s (a past run's)",
                h.epoch, self.epoch
            ));
        }
        let same = |p: &Pending| p.epoch == h.epoch && p.version == h.version && p.base == h.base;
        if !self.pending.iter().any(same) {
            self.pending.push(Pending { epoch: h.epoch, base: h.base, version: h.version, stamp, bytes });
        }
        Ok(self.drain(scratch))
    }

    /// Applies what waits, in order, as far as it goes; drops what is
    /// behind the copy, and the oldest beyond [`PENDING_LIMIT`].
    fn drain(&mut self, scratch: &mut [u32]) -> Offered {
        let mut done = Offered::default();
        while let Some(i) = self.next() {
            let p = self.pending.swap_remove(i);
            let new_epoch = self.epoch != Some(p.epoch);
            match self.replica.apply(&p.bytes, scratch) {
                Applied::Applied => {
                    done.applied += 1;
                    done.restarted |= new_epoch && self.epoch.is_some();
                    self.epoch = Some(p.epoch);
                    self.newest = if new_epoch { p.stamp } else { self.newest.max(p.stamp) };
                }
                Applied::Diverged | Applied::Restarted => done.diverged += 1,
                Applied::Repeated | Applied::OutOfStep | Applied::Refused(_) => {}
            }
        }
        let (epoch, held, newest) = (self.epoch, self.replica.version(), self.newest);
        self.pending.retain(|p| match epoch {
            Some(e) if p.epoch == e => p.version > held,
            Some(_) => p.stamp > newest,
            None => true,
        });
        if self.pending.len() > PENDING_LIMIT {
            self.pending.sort_by_key(|p| std::cmp::Reverse(p.stamp));
            self.pending.truncate(PENDING_LIMIT);
        }
        done
    }

    /// The update to apply next: the one after the version held, else the
    /// newest snapshot ahead of it (of the epoch followed, or of a newer
    /// one).
    fn next(&self) -> Option<usize> {
        let held = self.replica.version();
        let ours = |p: &Pending| Some(p.epoch) == self.epoch;
        if let Some(i) = self.pending.iter().position(|p| ours(p) && held != 0 && p.base == held) {
            return Some(i);
        }
        let ahead = |p: &Pending| p.base == 0 && if ours(p) { p.version > held } else { p.stamp > self.newest };
        self.pending
            .iter()
            .enumerate()
            .filter(|(_, p)| ahead(p))
            .max_by_key(|(_, p)| (p.stamp, p.version))
            .map(|(i, _)| i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cosem_core::classes::Class;
    use cosem_core::map::{FullPolicy, MapConfig};
    use cosem_core::session::{Publisher, ShadowEntry};

    fn map() -> HostMap {
        let config =
            MapConfig { when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] }, ..MapConfig::with_resolution(0.5) };
        crate::maps::mapping::new_map(4_000, config).unwrap()
    }

    /// A robot driving along a street, its updates as a broadcast makes
    /// them: (stamp, bytes), a snapshot every `every`.
    fn broadcast(epoch: u16, rounds: usize, every: usize, t0: i64) -> (Vec<(i64, Vec<u8>)>, HostMap) {
        let mut m = map();
        let mut p = Publisher::new(epoch, vec![ShadowEntry::default(); 4_000], vec![ShadowEntry::default(); 4_000]);
        let (mut scratch, mut out) = (vec![0u32; 8_000], vec![0u8; 1 << 16]);
        let mut log = Vec::new();
        for r in 0..rounds {
            let x = r as f32 * 2.0;
            m.move_anchor([x, 0.0, 0.0]).unwrap();
            for k in 0..400 {
                let a = x - 10.0 + k as f32 * 0.05;
                m.insert_point([a, 5.0, (k % 7) as f32 * 0.4], Class::Building).unwrap();
                m.insert_point([a, -4.0 + (k % 16) as f32 * 0.5, 0.0], Class::Road).unwrap();
            }
            if r % every == 0 {
                p.snapshot_next();
            }
            let n = p.next_update(&m, &mut scratch, &mut out).unwrap();
            p.delivered();
            log.push((t0 + r as i64, out[..n].to_vec()));
        }
        (log, m)
    }

    fn same(a: &HostMap, b: &HostMap) -> bool {
        let cells = |m: &HostMap| {
            let mut v: Vec<_> = m.iter().map(|v| (v.key, v.class())).collect();
            v.sort();
            v
        };
        cells(a) == cells(b)
    }

    #[test]
    fn updates_out_of_order_wait_for_their_base() {
        let (log, _) = broadcast(9, 12, 5, 100);
        let mut scratch = vec![0u32; 8_000];
        let mut inorder = Follower::new(map());
        for (s, b) in &log {
            assert_eq!(inorder.offer(*s, b.clone(), &mut scratch).unwrap().applied, 1);
        }
        // The same updates, the snapshots last (their own topic, late).
        let mut shuffled = Follower::new(map());
        let (snaps, deltas): (Vec<_>, Vec<_>) = log.iter().enumerate().partition(|(i, _)| i % 5 == 0);
        for (_, (s, b)) in deltas.iter().chain(&snaps) {
            shuffled.offer(*s, b.clone(), &mut scratch).unwrap();
        }
        assert_eq!(shuffled.version(), inorder.version());
        assert!(same(shuffled.map(), inorder.map()));
        assert_eq!(shuffled.waiting(), 0);
    }

    #[test]
    fn a_late_joiner_catches_up_and_a_restart_replaces_the_copy() {
        let (log, _) = broadcast(9, 12, 5, 100);
        let mut scratch = vec![0u32; 8_000];
        // Joins at update 7: the last snapshot (5) and the updates after.
        let mut late = Follower::new(map());
        for (s, b) in log.iter().skip(5) {
            late.offer(*s, b.clone(), &mut scratch).unwrap();
        }
        let mut all = Follower::new(map());
        for (s, b) in &log {
            all.offer(*s, b.clone(), &mut scratch).unwrap();
        }
        assert_eq!(late.version(), all.version());
        assert!(same(late.map(), all.map()));
        // A damaged update is an error; nothing changes.
        let mut bad = log[11].1.clone();
        let k = bad.len() / 2;
        bad[k] ^= 0x40;
        assert!(late.offer(200, bad, &mut scratch).unwrap_err().contains("malformed"));
        assert!(late.offer(200, log[11].1[..10].to_vec(), &mut scratch).is_err());
        assert!(same(late.map(), all.map()));
        // The peer restarts: its new epoch's snapshot replaces the copy; a
        // stale sample of the old epoch after it is refused.
        let (again, now) = broadcast(10, 3, 5, 1_000);
        let mut restarted = false;
        for (s, b) in &again {
            restarted |= late.offer(*s, b.clone(), &mut scratch).unwrap().restarted;
        }
        assert!(restarted);
        assert_eq!(late.epoch(), Some(10));
        assert!(same(late.map(), &now));
        assert!(late.offer(150, log[10].1.clone(), &mut scratch).unwrap_err().contains("past run"));
        // A new epoch's update before its snapshot waits for it.
        let (third, latest) = broadcast(11, 2, 5, 2_000);
        assert_eq!(late.offer(third[1].0, third[1].1.clone(), &mut scratch).unwrap().applied, 0);
        let got = late.offer(third[0].0, third[0].1.clone(), &mut scratch).unwrap();
        assert_eq!((got.applied, got.restarted), (2, true));
        assert!(same(late.map(), &latest));
    }
}
