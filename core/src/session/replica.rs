//! The receiving side of map updates: the peer's map, kept equal to
//! `decode(encode(peer's map at version v))`.

use crate::map::{ConfigError, InsertError, LocalMap, MapConfig, SemanticVoxel, VoxelSink, VoxelStorage};
use crate::wire::codec::{morton, stream_order, update_record, voxel_of_record, DecodeError};
use crate::wire::update::{voxel_hash, ChangeSink, UpdateAck, UpdateError, UpdateModel, UpdateView};

/// What became of an update.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Applied {
    /// Applied: the copy is the peer's map at the update's version, its
    /// digest checked.
    Applied,
    /// The version held already (a repeated update): nothing changed.
    Repeated,
    /// For another version than the one held (an update before it was
    /// lost, or an answer was): nothing changed; the answer says what is
    /// held, so that the peer resends from there or sends a snapshot.
    OutOfStep,
    /// Damaged or malformed: nothing changed.
    Refused(UpdateError),
    /// Applied, but the copy did not come out as the peer's map (digest or
    /// count): the copy is emptied and a snapshot asked for.
    Diverged,
    /// A new epoch (the peer restarted) that did not start with a
    /// snapshot: the copy is emptied and a snapshot asked for.
    Restarted,
}

impl Applied {
    /// Its wire byte (a session robot's round report): 0 applied, 1
    /// repeated, 2 out of step, 3 refused, 4 diverged, 5 restarted.
    pub fn code(self) -> u8 {
        match self {
            Applied::Applied => 0,
            Applied::Repeated => 1,
            Applied::OutOfStep => 2,
            Applied::Refused(_) => 3,
            Applied::Diverged => 4,
            Applied::Restarted => 5,
        }
    }
}

/// A voxel's share of the copy's digest.
fn hash_of(v: &SemanticVoxel) -> u32 {
    voxel_hash(morton(v.key), update_record(v))
}

/// Decodes into a map, replacing the voxel of a cell held already, and
/// keeps the map's digest (the voxel replaced out, the one written in).
struct Upsert<'m, S: VoxelStorage> {
    map: &'m mut LocalMap<S>,
    digest: &'m mut u32,
}

impl<S: VoxelStorage> VoxelSink for Upsert<'_, S> {
    fn len(&self) -> usize {
        self.map.len()
    }
    fn capacity(&self) -> usize {
        self.map.capacity()
    }
    fn resolution(&self) -> f32 {
        self.map.resolution()
    }
    fn clear(&mut self) {
        self.map.clear();
        *self.digest = 0;
    }
    fn configure(&mut self, config: MapConfig) -> Result<(), ConfigError> {
        self.map.reset(config)?;
        *self.digest = 0;
        Ok(())
    }
    fn accept(&mut self, voxel: SemanticVoxel) -> Result<(), InsertError> {
        let replaced = self.map.get(voxel.key).map(hash_of);
        self.map.upsert_voxel(voxel)?;
        *self.digest = self.digest.wrapping_sub(replaced.unwrap_or(0)).wrapping_add(hash_of(&voxel));
        Ok(())
    }
}

/// Gives cells of the copy, named by their rank in its Morton order
/// (`order`: the copy's indices in that order), the records an update's
/// changed voxels carry, and keeps the copy's digest.
struct Rewrite<'m, S: VoxelStorage> {
    map: &'m mut LocalMap<S>,
    order: &'m [u32],
    digest: &'m mut u32,
}

impl<S: VoxelStorage> Rewrite<'_, S> {
    fn voxel(&self, rank: u32) -> Option<&SemanticVoxel> {
        self.order.get(rank as usize).and_then(|&i| self.map.voxel(i as usize))
    }
}

impl<S: VoxelStorage> ChangeSink for Rewrite<'_, S> {
    fn held(&mut self, rank: u32) -> Option<u32> {
        self.voxel(rank).map(update_record)
    }
    fn change(&mut self, rank: u32, held: u32, record: u32) -> Result<(), DecodeError> {
        let key = self.voxel(rank).ok_or(DecodeError::Range)?.key;
        let new = voxel_of_record(key, record)?;
        self.map.upsert_voxel(new).map_err(|_| DecodeError::Full)?;
        let old = voxel_hash(morton(key), held);
        *self.digest = self.digest.wrapping_sub(old).wrapping_add(hash_of(&new));
        Ok(())
    }
}

/// A robot's copy of its peer's map, in caller-owned storage (at least
/// the capacity the robot announces in its answers).
pub struct Replica<S: VoxelStorage> {
    map: LocalMap<S>,
    epoch: Option<u16>,
    version: u32,
    digest: u32,
    /// The codec models as decoding the update that made `version` left
    /// them: the next update is decoded from them ([`crate::wire::update`]).
    model: UpdateModel,
    /// Where the peer was when it last cut its map ([`Replica::peer_place`]).
    peer_place: Option<[f32; 3]>,
}

impl<S: VoxelStorage> Replica<S> {
    /// An empty copy over `map` (its configuration: the peer's voxel size).
    pub fn new(mut map: LocalMap<S>) -> Self {
        map.clear();
        Replica { map, epoch: None, version: 0, digest: 0, model: UpdateModel::new(), peer_place: None }
    }

    /// The copy (the peer's map at [`Replica::version`]).
    pub fn map(&self) -> &LocalMap<S> {
        &self.map
    }

    /// The version held (0: none).
    pub fn version(&self) -> u32 {
        self.version
    }

    /// Where the peer was (its own frame), as the last applied update that
    /// cut its map said (a full map cuts about where its robot is, every
    /// round it drives; a scan or two behind at most); `None` before any,
    /// or since the peer restarted. What a robot's agreement with its
    /// peer's estimate is judged at besides its own place
    /// ([`crate::session::PeerView::peer_at`]).
    pub fn peer_place(&self) -> Option<[f32; 3]> {
        self.peer_place
    }

    /// The answer that says what is held.
    pub fn answer(&self) -> UpdateAck {
        UpdateAck {
            epoch: self.epoch.unwrap_or(0),
            version: self.version,
            digest: self.digest,
            capacity: self.map.capacity() as u32,
        }
    }

    fn forget(&mut self) {
        self.map.clear();
        self.version = 0;
        self.digest = 0;
    }

    /// Applies an update (`scratch`: a `u32` per voxel of the copy's
    /// capacity; two: faster), and says what became of it;
    /// [`Replica::answer`] is what to send back.
    pub fn apply(&mut self, bytes: &[u8], scratch: &mut [u32]) -> Applied {
        let view = match UpdateView::parse(bytes) {
            Ok(v) => v,
            Err(e) => return Applied::Refused(e),
        };
        let h = view.header;
        if self.epoch != Some(h.epoch) {
            self.epoch = Some(h.epoch);
            self.peer_place = None;
            self.forget();
            if h.base != 0 {
                return Applied::Restarted;
            }
        }
        if h.version == self.version && h.digest == self.digest && self.version != 0 {
            return Applied::Repeated;
        }
        if h.base != 0 && h.base != self.version {
            return Applied::OutOfStep;
        }
        if h.base == 0 {
            self.forget();
        }
        // The copy's digest kept as the update is applied (0: emptied).
        let mut digest = self.digest;
        if self.patch(&view, scratch, &mut digest).is_err() {
            self.forget();
            return Applied::Diverged;
        }
        if digest != h.digest || self.map.len() != h.voxels as usize {
            self.forget();
            return Applied::Diverged;
        }
        self.version = h.version;
        self.digest = h.digest;
        if let Some(cut) = view.cut {
            self.peer_place = Some(cut.centre_m(self.map.resolution()));
        }
        Applied::Applied
    }

    /// The update's changes, removals and upserts applied to the copy, its
    /// digest and codec models kept (a failure empties the copy: the next
    /// update is a snapshot, from fresh models).
    fn patch(&mut self, view: &UpdateView<'_>, scratch: &mut [u32], digest: &mut u32) -> Result<(), ()> {
        // Cells named by rank: the copy in code order (the base's ranks) in
        // the scratch. A changed voxel keeps its place in the copy.
        let ranked = view.header.removals > 0 || view.header.changed > 0;
        let order = if ranked { stream_order(&self.map, scratch).map_err(|_| ())? } else { &mut [][..] };
        let mut rewrite = Rewrite { map: &mut self.map, order, digest: &mut *digest };
        view.decode_changes(&mut self.model.changes, &mut rewrite).map_err(|_| ())?;
        if view.header.removals > 0 || view.cut.is_some() {
            // The indices of the ranks removed moved to the front of the
            // order (rank k is at or after slot k: nothing unread is
            // overwritten), sorted.
            let mut gone = 0;
            if view.header.removals > 0 {
                let order = scratch.get_mut(..self.map.len()).ok_or(())?;
                for rank in view.removed() {
                    let i = *order.get(rank as usize).ok_or(())?;
                    *order.get_mut(gone).ok_or(())? = i;
                    gone += 1;
                }
            }
            let gone = scratch.get_mut(..gone).ok_or(())?;
            gone.sort_unstable();
            // Each cell goes once, named by rank, by the cut or both.
            let (mut i, mut next) = (0u32, 0usize);
            self.map.retain(|v| {
                let ranked = gone.get(next) == Some(&i);
                next += usize::from(ranked);
                i += 1;
                let drop = ranked || view.cut.is_some_and(|c| c.removes(v.key));
                if drop {
                    *digest = digest.wrapping_sub(hash_of(v));
                }
                !drop
            });
        }
        view.decode_upserts(&mut self.model.voxels, &mut Upsert { map: &mut self.map, digest }).map_err(|_| ())
    }
}
