//! The sending side of map updates: what the peer holds, and what changed
//! since. A peer that holds fewer voxels than the map (its answers say how
//! many) is sent the part that fits: the voxels nearest where the map
//! keeps them ([`LocalMap::keep_centre`], [`LocalMap::nearest`]); the
//! versions and digests are then those of that part.
//!
//! A voxel already held is resent only when its record moved beyond the
//! deadband ([`within_step`]: its class, a step of its confidence, two
//! quarter cells of its mean; its occupancy, which matching never reads,
//! not compared): a LiDAR that keeps driving nudges the mean and
//! confidence of every voxel it sees, and resending each nudge made an
//! update half the map. What the peer holds, and what the digests cover,
//! is the map as published: each voxel's record as last sent, never
//! further than the deadband from the map's. An update carries no
//! occupancy ([`update_record`]): the peer holds each voxel at one hit.
//!
//! An update may be bounded ([`Publisher::set_budget`]): what changed
//! beyond the budget waits for the next rounds, changed voxels before new
//! ones and the farthest from the robot first; what the peer holds is then
//! the map as published with those held back.
//!
//! The cells that left the map go by a [`Cut`] where they can: every cell
//! the peer holds at least as far from where the map keeps its voxels (or
//! where it last evicted, whichever names more) as the farthest one it
//! keeps; the rest by rank.

use crate::map::{LocalMap, VoxelStorage};
use crate::wire::codec::{key_of, morton, update_record, within_step, EncodeError, MapEncoder};
use crate::wire::update::{
    digest_of, write_update, Cut, Removed, UpdateAck, UpdateError, UpdateHeader, UpdateModel, ACK_BYTES,
    MIN_UPDATE_BUDGET,
};

/// One voxel's record as a peer holds it: its cell (Morton code) and what
/// the wire carried of it ([`update_record`]); where it is in the sender's
/// map now.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShadowEntry {
    /// Morton code of the cell.
    pub code: u64,
    /// The voxel's [`update_record`] as published.
    pub record: u32,
    /// Its index in the sender's map when the record was taken.
    pub index: u32,
}

/// How much a round's update may take ([`Publisher::set_budget`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UpdateBudget {
    /// At most this many bytes: a link's rate.
    Bytes(u32),
    /// At most this many thousandths of what the map would take sent
    /// whole (a snapshot of the part the peer can hold), the peer's answer
    /// ([`ACK_BYTES`]) included: a share of the map, whatever its labels
    /// make a voxel cost. A cleaner map codes smaller, so a fixed number
    /// of bytes is a larger share of it. Measured each round by writing
    /// the snapshot, so it costs one more update's writing.
    PerMille(u16),
}

impl UpdateBudget {
    /// Whether the budget can be kept: at least [`MIN_UPDATE_BUDGET`]
    /// bytes, or 1 to 1,000 thousandths.
    pub fn is_valid(self) -> bool {
        match self {
            UpdateBudget::Bytes(b) => b >= MIN_UPDATE_BUDGET,
            UpdateBudget::PerMille(m) => (1..=1000).contains(&m),
        }
    }

    /// The bytes an update may take when the map sent whole takes `whole`
    /// (never under [`MIN_UPDATE_BUDGET`]).
    pub fn bytes(self, whole: usize) -> u32 {
        match self {
            UpdateBudget::Bytes(b) => b,
            UpdateBudget::PerMille(m) => {
                let share = (whole as u64).saturating_mul(u64::from(m)) / 1000;
                let share = u32::try_from(share).unwrap_or(u32::MAX);
                share.saturating_sub(ACK_BYTES as u32).max(MIN_UPDATE_BUDGET)
            }
        }
    }
}

/// Why no update could be written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PublisherError {
    /// The records' storage is smaller than the map.
    Records,
    /// The scratch is smaller than the map.
    Scratch,
    /// The update did not fit the output.
    Update(UpdateError),
}

impl From<EncodeError> for PublisherError {
    fn from(_: EncodeError) -> Self {
        PublisherError::Scratch
    }
}

impl core::fmt::Display for PublisherError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PublisherError::Records => f.write_str("update records smaller than the map"),
            PublisherError::Scratch => f.write_str("update scratch smaller than the map"),
            PublisherError::Update(e) => write!(f, "{e}"),
        }
    }
}

impl core::error::Error for PublisherError {}

/// What the last update held.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UpdateCounts {
    /// Voxels the peer did not hold.
    pub new: u32,
    /// Voxels the peer held with another record.
    pub changed: u32,
    /// Cells removed.
    pub removed: u32,
    /// New or changed voxels held back for a later update: beyond the
    /// budget ([`Publisher::set_budget`]).
    pub deferred: u32,
    /// A snapshot (the peer held nothing).
    pub snapshot: bool,
}

/// The sending side: the records of what the peer acknowledged (`held`)
/// and of the update in flight (`sent`), both in caller-owned storage of
/// the map's capacity (`&mut [ShadowEntry]` on a board, a `Vec` on a host).
pub struct Publisher<R: AsRef<[ShadowEntry]> + AsMut<[ShadowEntry]>> {
    epoch: u16,
    /// The last version made.
    version: u32,
    /// The version the peer holds (0: none: the next update is a snapshot).
    acked: u32,
    held: R,
    held_len: usize,
    sent: R,
    sent_len: usize,
    /// The version and digest of the update in flight.
    in_flight: Option<(u32, u32)>,
    /// Voxels the peer can hold (from its answers).
    peer_capacity: u32,
    /// What the last update held.
    counts: UpdateCounts,
    /// The codec models as encoding the update the peer acknowledged left
    /// them, and as encoding the update in flight did: the next update is
    /// coded from the first ([`crate::wire::update`]).
    held_model: UpdateModel,
    sent_model: UpdateModel,
    /// What an update (not a snapshot) may take, if bounded.
    budget: Option<UpdateBudget>,
}

impl ShadowEntry {
    /// No record (what a board's static records start as).
    pub const EMPTY: ShadowEntry = ShadowEntry { code: 0, record: 0, index: 0 };
}

impl<R: AsRef<[ShadowEntry]> + AsMut<[ShadowEntry]>> Publisher<R> {
    /// A publisher of session `epoch` (a restarted robot takes another),
    /// its records in `held` and `sent` (each at least the map's capacity).
    pub fn new(epoch: u16, held: R, sent: R) -> Self {
        Publisher {
            epoch,
            version: 0,
            acked: 0,
            held,
            held_len: 0,
            sent,
            sent_len: 0,
            in_flight: None,
            peer_capacity: u32::MAX,
            counts: UpdateCounts::default(),
            held_model: UpdateModel::new(),
            sent_model: UpdateModel::new(),
            budget: None,
        }
    }

    /// Bounds each update to `budget` (`None`: unbounded; a snapshot never
    /// is: the peer needs it whole). A round that changed more sends what
    /// changed nearest the map's keep centre (the robot), changed voxels
    /// after new ones, and holds the rest back, as the peer holds it, for
    /// the next rounds: a link's rate bounds what a round may send, and a
    /// robot that turns into a new street changes twice what a straight one
    /// does. The cells that left the map and the header are always sent, so
    /// an update exceeds the budget only when they alone do. Set in place:
    /// a publisher holds two codec models, which a board's stack should not
    /// carry by value.
    pub fn set_budget(&mut self, budget: Option<UpdateBudget>) {
        self.budget = budget;
    }

    /// The session's epoch.
    pub fn epoch(&self) -> u16 {
        self.epoch
    }

    /// The version the peer acknowledged (0: none).
    pub fn acked(&self) -> u32 {
        self.acked
    }

    /// The last version made.
    pub fn version(&self) -> u32 {
        self.version
    }

    /// The map as the last update published it, in code order: each
    /// voxel's cell and record, exactly what a copy that applied it holds
    /// (each record within a step of the map's then).
    pub fn published(&self) -> &[ShadowEntry] {
        match self.in_flight {
            Some(_) => self.sent.as_ref().get(..self.sent_len).unwrap_or(&[]),
            None => self.held.as_ref().get(..self.held_len).unwrap_or(&[]),
        }
    }

    /// What the last update held.
    pub fn counts(&self) -> UpdateCounts {
        self.counts
    }

    /// Writes the update that brings the peer from what it acknowledged to
    /// `map` now into `out` (a snapshot when it acknowledged nothing), and
    /// returns its length. `scratch`: a `u32` per voxel of the map (two:
    /// faster). It supersedes the update in flight.
    pub fn next_update<S: VoxelStorage>(
        &mut self,
        map: &LocalMap<S>,
        scratch: &mut [u32],
        out: &mut [u8],
    ) -> Result<usize, PublisherError> {
        self.in_flight = None;
        // The part the peer can hold (all of a map that fits), its stream
        // order and digest.
        let n = map.nearest(map.keep_centre(), self.peer_capacity as usize, scratch);
        if n < map.len().min(self.peer_capacity as usize) {
            return Err(PublisherError::Scratch);
        }
        let part = MapEncoder::subset_continuing(map, &mut *scratch, n)?;
        let order = part.into_scratch();
        let records = self.sent.as_mut().get_mut(..n).ok_or(PublisherError::Records)?;
        for (r, &i) in records.iter_mut().zip(order.iter()) {
            let v = map.voxel(i as usize).ok_or(PublisherError::Scratch)?;
            *r = ShadowEntry { code: morton(v.key), record: update_record(v), index: i };
        }
        // In stream order already: sorted by code.
        self.sent_len = n;
        let snapshot = self.acked == 0;
        let held = if snapshot { 0 } else { self.held_len };
        // A share is of the map as it is, before the deadband keeps records.
        let budget = match self.budget.filter(|_| !snapshot) {
            Some(UpdateBudget::Bytes(b)) => Some(b),
            Some(b) => Some(b.bytes(self.whole_len(map, scratch, out)?)),
            None => None,
        };
        let records = self.sent.as_mut().get_mut(..n).ok_or(PublisherError::Records)?;
        keep_held_within_step(self.held.as_ref().get(..held).unwrap_or(&[]), records);
        let mut written = self.write(map, held, scratch, out)?;
        let mut deferred = 0;
        if let Some(budget) = budget {
            let centre = Cut::about(map.keep_centre(), map.resolution());
            for pass in 0..2 * MAX_BUDGET_PASSES {
                if written.len <= budget as usize || written.candidates == 0 {
                    break;
                }
                // Bytes a voxel sent, over-counted by the header and the
                // removals: a pass defers a little more than it must.
                let over = written.len - budget as usize;
                // Passes that kept falling short (the voxels held back were
                // the cheap ones) defer twice as many each from then on.
                let more = 1 << pass.saturating_sub(MAX_BUDGET_PASSES - 1);
                let want = ((over * written.candidates).div_ceil(written.len) + 1) * more;
                let held_records = self.held.as_ref().get(..held).unwrap_or(&[]);
                let records = self.sent.as_mut().get_mut(..self.sent_len).ok_or(PublisherError::Records)?;
                let (kept, d) = defer_farthest(held_records, records, centre, want);
                self.sent_len = kept;
                deferred += d;
                written = self.write(map, held, scratch, out)?;
            }
        }
        let version = self.version.wrapping_add(1).max(1);
        self.version = version;
        self.in_flight = Some((version, written.digest));
        self.counts = UpdateCounts { deferred, snapshot, ..written.counts };
        Ok(written.len)
    }

    /// The bytes of the records in flight sent whole: the first update a
    /// fresh publisher would send (a snapshot, version 1), written into
    /// `out` and left there for the update that follows to overwrite.
    fn whole_len<S: VoxelStorage>(
        &mut self,
        map: &LocalMap<S>,
        scratch: &mut [u32],
        out: &mut [u8],
    ) -> Result<usize, PublisherError> {
        let (acked, version) = (core::mem::replace(&mut self.acked, 0), core::mem::replace(&mut self.version, 0));
        let written = self.write(map, 0, scratch, out);
        (self.acked, self.version) = (acked, version);
        Ok(written?.len)
    }

    /// Writes the update from the first `held` records the peer holds to
    /// the records in flight (as the next version), from the acknowledged
    /// update's codec model. Never inlined: its codec model and encoder
    /// stay one frame on a board's stack, not one per call site.
    #[inline(never)]
    fn write<S: VoxelStorage>(
        &mut self,
        map: &LocalMap<S>,
        held: usize,
        scratch: &mut [u32],
        out: &mut [u8],
    ) -> Result<Written, PublisherError> {
        let held = self.held.as_ref().get(..held).unwrap_or(&[]);
        let records = self.sent.as_ref().get(..self.sent_len).unwrap_or(&[]);
        let snapshot = self.acked == 0;
        let digest = digest_of(records.iter().map(|r| (r.code, r.record)));
        // The cells beyond the farthest one kept go by the cut, about where
        // the map keeps its voxels or where it last evicted (a scan or two
        // behind): whichever leaves fewer cells to name by rank.
        let about = |c: [f32; 3]| cut_for(held, records, Cut::about(c, map.resolution()));
        let (mut cut, left) = about(map.keep_centre());
        if let Some((other, _)) = map.last_cut_centre().map(about).filter(|&(_, n)| n < left) {
            cut = other;
        }
        let by_cut = |code: u64| cut.is_some_and(|c| key_of(code).is_some_and(|k| c.removes(k)));
        // The voxels new, as indices of the map.
        let (mut upserts, mut changed, mut removals, mut cut_away) = (0, 0, 0, 0);
        for change in Changes::new(held, records) {
            match change {
                Change::New(index) => {
                    *scratch.get_mut(upserts).ok_or(PublisherError::Scratch)? = index;
                    upserts += 1;
                }
                Change::Changed { .. } => changed += 1,
                Change::Remove(_, code) if by_cut(code) => cut_away += 1,
                Change::Remove(..) => removals += 1,
            }
        }
        let ranks = Changes::new(held, records).filter_map(|c| match c {
            Change::Remove(rank, code) if !by_cut(code) => Some(rank),
            _ => None,
        });
        let changes = Changes::new(held, records).filter_map(|c| match c {
            Change::Changed { rank, held, now } => Some((rank, held, now)),
            _ => None,
        });
        let header = UpdateHeader {
            epoch: self.epoch,
            base: if snapshot { 0 } else { self.acked },
            version: self.version.wrapping_add(1).max(1),
            voxels: records.len() as u32,
            digest,
            removals: removals as u32,
            upserts: upserts as u32,
            changed,
        };
        // Coded from the acknowledged update's model, into the one in flight.
        self.sent_model = if snapshot { UpdateModel::new() } else { self.held_model };
        let mut encoder = MapEncoder::subset_continuing(map, scratch, upserts)?.without_occupancy();
        let removed = Removed { cut, ranks, count: removals };
        let len = write_update(&header, removed, changes, Some(&mut encoder), &mut self.sent_model, out)
            .map_err(PublisherError::Update)?;
        let removed = (removals + cut_away) as u32;
        let counts = UpdateCounts { new: upserts as u32, changed, removed, deferred: 0, snapshot };
        Ok(Written { len, digest, counts, candidates: upserts + changed as usize })
    }

    /// Takes the update in flight as delivered: what a transport that
    /// broadcasts to every peer, with no answers, does (a ROS 2 node's map
    /// updates over DDS). The next update is made against it; a peer that
    /// missed one waits for a snapshot ([`Publisher::snapshot_next`]).
    pub fn delivered(&mut self) {
        if let Some((version, digest)) = self.in_flight {
            let capacity = self.peer_capacity;
            self.on_ack(&UpdateAck { epoch: self.epoch, version, digest, capacity });
        }
    }

    /// Makes the next update a snapshot (the whole map, against nothing):
    /// on a broadcast, every so often, so that a peer that missed an
    /// update or joined late catches up. The updates after it are made
    /// against it.
    pub fn snapshot_next(&mut self) {
        self.in_flight = None;
        self.acked = 0;
        self.held_len = 0;
    }

    /// Takes the peer's answer: what it holds now. The update in flight
    /// acknowledged, its records become what the peer holds; the version
    /// acknowledged before, the next update is again from it (the update
    /// was lost); anything else (another version, a digest that differs,
    /// nothing held), the next update is a snapshot. Of an answer to
    /// another epoch only the capacity is taken: a peer's first answer,
    /// sent before any update (as a link's `Hello`), says what it holds, so
    /// that not even the first update is more than that.
    pub fn on_ack(&mut self, ack: &UpdateAck) {
        self.peer_capacity = ack.capacity;
        if ack.epoch != self.epoch {
            return;
        }
        match self.in_flight {
            Some((v, d)) if ack.version == v && ack.digest == d => {
                core::mem::swap(&mut self.held, &mut self.sent);
                self.held_model = self.sent_model;
                self.held_len = self.sent_len;
                self.acked = v;
                self.in_flight = None;
            }
            _ if ack.version == self.acked && ack.version != 0 => {}
            _ => {
                self.acked = 0;
                self.held_len = 0;
            }
        }
    }
}

/// Gives each voxel of `now` (the map's records, sorted by code) that
/// `held` (the peer's, sorted by code) has within a step the held record:
/// it is not resent.
fn keep_held_within_step(held: &[ShadowEntry], now: &mut [ShadowEntry]) {
    for_each_candidate(held, now, |r, h| {
        if let Some(h) = h.filter(|&h| within_step(h, r.record)) {
            r.record = h;
        }
    });
}

/// An update written: its length, digest and counts, and how many of its
/// voxels (new or changed) a budget could hold back.
struct Written {
    len: usize,
    digest: u32,
    counts: UpdateCounts,
    candidates: usize,
}

/// Passes of writing an update within its budget: each defers a little
/// more than the last one's excess asked, so two mostly do; as many more
/// again, each deferring twice the last, for the rare update these leave
/// a few bytes over.
const MAX_BUDGET_PASSES: usize = 6;

/// Cells from the keep centre, at most: the histogram's last bin holds the
/// rest.
const DEFER_BINS: usize = 128;

/// A record's code while it is being dropped: beyond any Morton code (48
/// bits).
const DROPPED: u64 = u64::MAX;

/// Calls `f` on each record of `now` (sorted by code) that `held` (sorted
/// by code) does not hold, or holds with another record (then given).
fn for_each_candidate(held: &[ShadowEntry], now: &mut [ShadowEntry], mut f: impl FnMut(&mut ShadowEntry, Option<u32>)) {
    let mut held = held.iter().peekable();
    for r in now.iter_mut() {
        while held.next_if(|h| h.code < r.code).is_some() {}
        match held.next_if(|h| h.code == r.code) {
            Some(h) if h.record != r.record => f(r, Some(h.record)),
            Some(_) => {}
            None => f(r, None),
        }
    }
}

/// Holds back `want` of the voxels `now` (sorted by code) has new or
/// changed against `held` (sorted by code) (all of them, if fewer), the
/// farthest from `centre` first by whole cells of distance (within a cell's
/// distance, in code order), changed ones before new ones: a new one leaves the records,
/// a changed one takes its held record again (as the deadband does).
/// Returns the records' new length and how many were held back.
#[inline(never)]
fn defer_farthest(held: &[ShadowEntry], now: &mut [ShadowEntry], centre: Cut, want: usize) -> (usize, u32) {
    // Whole cells from the centre (the cut's units are 32nds of a cell).
    let bin = |code: u64| {
        let d = key_of(code).map_or(u64::MAX, |k| centre.distance_sq(k));
        (d.isqrt() / 32).min(DEFER_BINS as u64 - 1) as usize
    };
    // Changed voxels are held back before new ones (the peer holds them
    // already, a little off), each the farthest first.
    let rank = |r: &ShadowEntry, held: Option<u32>| bin(r.code) + if held.is_some() { DEFER_BINS } else { 0 };
    let mut histogram = [0u32; 2 * DEFER_BINS];
    for_each_candidate(held, now, |r, h| {
        if let Some(n) = histogram.get_mut(rank(r, h)) {
            *n += 1;
        }
    });
    // The lowest rank from which on `want` are held back: all of the ranks
    // above it, and of its own the first in code order that make up the
    // rest.
    let (mut from, mut total) = (histogram.len(), 0usize);
    while from > 0 && total < want {
        from -= 1;
        total += histogram.get(from).copied().unwrap_or(0) as usize;
    }
    let mut at_from = (want + histogram.get(from).copied().unwrap_or(0) as usize).saturating_sub(total);
    let mut deferred = 0u32;
    for_each_candidate(held, now, |r, held_record| {
        let rank = rank(r, held_record);
        let defer = rank > from || (rank == from && at_from > 0);
        if defer {
            at_from -= usize::from(rank == from);
            deferred += 1;
            match held_record {
                Some(h) => r.record = h,
                None => r.code = DROPPED,
            }
        }
    });
    // The new ones held back leave the records, the order kept.
    let mut kept = 0;
    for i in 0..now.len() {
        let Some(r) = now.get(i).copied().filter(|r| r.code != DROPPED) else { continue };
        if let Some(slot) = now.get_mut(kept) {
            *slot = r;
        }
        kept += 1;
    }
    (kept, deferred)
}

/// The cut that removes every cell of `held` (sorted by code) at least as
/// far from `about`'s centre as the farthest one `now` (sorted by code)
/// still has: none when that removes nothing (nothing left, or only
/// nearer cells did). On a map that keeps driving, the far side of its
/// ball.
fn cut_for(held: &[ShadowEntry], now: &[ShadowEntry], about: Cut) -> (Option<Cut>, usize) {
    let kept = |now: &mut core::iter::Peekable<core::slice::Iter<'_, ShadowEntry>>, h: &ShadowEntry| {
        while now.next_if(|n| n.code < h.code).is_some() {}
        now.peek().is_some_and(|n| n.code == h.code)
    };
    let distance = |h: &ShadowEntry| key_of(h.code).map_or(0, |k| about.distance_sq(k));
    let mut it = now.iter().peekable();
    let far_kept = held.iter().filter(|h| kept(&mut it, h)).map(distance).max();
    let threshold = far_kept.map_or(0, |d| d + 1);
    // The cells gone, by the cut or else by rank.
    let (mut cut_away, mut ranked) = (0usize, 0usize);
    let mut it = now.iter().peekable();
    for h in held.iter().filter(|h| !kept(&mut it, h)) {
        if distance(h) >= threshold {
            cut_away += 1;
        } else {
            ranked += 1;
        }
    }
    ((cut_away > 0).then_some(Cut { threshold, ..about }), ranked)
}

/// A difference between what the peer holds and the map now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Change {
    /// The voxel at this index of the map is new.
    New(u32),
    /// The cell of this rank in what the peer holds (in code order) has
    /// another record now.
    Changed { rank: u32, held: u32, now: u32 },
    /// The cell of this rank in what the peer holds (in code order), of
    /// this code, left the map.
    Remove(u32, u64),
}

/// The differences of two record lists, each sorted by code, in code order.
struct Changes<'a> {
    held: &'a [ShadowEntry],
    now: &'a [ShadowEntry],
    /// The rank of `held`'s first record in what the peer holds.
    rank: u32,
}

impl<'a> Changes<'a> {
    fn new(held: &'a [ShadowEntry], now: &'a [ShadowEntry]) -> Self {
        Changes { held, now, rank: 0 }
    }

    fn skip_held(&mut self) -> u32 {
        self.held = self.held.get(1..).unwrap_or(&[]);
        self.rank += 1;
        self.rank - 1
    }

    fn remove_held(&mut self, code: u64) -> Change {
        Change::Remove(self.skip_held(), code)
    }
}

impl Iterator for Changes<'_> {
    type Item = Change;
    fn next(&mut self) -> Option<Change> {
        loop {
            match (self.held.first(), self.now.first()) {
                (None, None) => return None,
                (Some(h), None) => return Some(self.remove_held(h.code)),
                (None, Some(n)) => {
                    self.now = self.now.get(1..).unwrap_or(&[]);
                    return Some(Change::New(n.index));
                }
                (Some(h), Some(n)) if h.code < n.code => return Some(self.remove_held(h.code)),
                (Some(h), Some(n)) if h.code > n.code => {
                    self.now = self.now.get(1..).unwrap_or(&[]);
                    return Some(Change::New(n.index));
                }
                (Some(h), Some(n)) => {
                    let rank = self.skip_held();
                    self.now = self.now.get(1..).unwrap_or(&[]);
                    if h.record != n.record {
                        return Some(Change::Changed { rank, held: h.record, now: n.record });
                    }
                }
            }
        }
    }
}
