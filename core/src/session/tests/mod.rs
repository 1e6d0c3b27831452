use super::*;
use crate::classes::Class;
use crate::map::{FullPolicy, MapConfig, SemanticVoxel, VecMap};
use crate::test_util::heap_map;
use crate::wire::codec::{update_record, voxel_record, within_step, CodecModel, MapDecoder, MapEncoder};
use crate::wire::update::{digest_of, UpdateAck, UpdateView};
use std::vec;
use std::vec::Vec;

/// A small deterministic generator (the tests' own: the session is below
/// the simulation's layer).
struct Lcg(u64);

impl Lcg {
    fn unit(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }
}

const CAPACITY: usize = 3_000;

fn map_config() -> MapConfig {
    MapConfig { when_full: FullPolicy::EvictFarthest { anchor: [0.0; 3] }, ..MapConfig::with_resolution(0.5) }
}

fn robot_map() -> VecMap {
    heap_map(CAPACITY, map_config())
}

/// One round of a robot driving a curve: it moves on, its map's anchor
/// with it, and fuses 1,500 points of a street (walls either side, ground,
/// poles) around where it is; the class of a point is its place's, one
/// in ten wrong.
fn drive(map: &mut VecMap, round: usize, rng: &mut Lcg) {
    let (x, y) = (3.0 * round as f32, 0.02 * (3.0 * round as f32).powi(2) / 10.0);
    map.move_anchor([x, y, 0.0]).unwrap();
    for _ in 0..1_500 {
        let (u, v) = (rng.unit(), rng.unit());
        let along = x - 20.0 + 40.0 * u;
        let (p, class) = match (v * 4.0) as u32 {
            0 => ([along, y + 6.0, 3.0 * rng.unit()], Class::Building),
            1 => ([along, y - 6.0, 3.0 * rng.unit()], Class::Vegetation),
            2 => ([along, y - 6.0 + 12.0 * rng.unit(), 0.0], Class::Road),
            _ => ([libm::floorf(along / 8.0) * 8.0, y + 4.0, 4.0 * rng.unit()], Class::Pole),
        };
        let class = if rng.unit() < 0.1 { Class::Car } else { class };
        map.insert_point(p, class).unwrap();
    }
}

/// `decode(encode(map))` as an update carries it (no occupancy): what a
/// peer's copy must equal.
fn decoded(map: &VecMap) -> Vec<SemanticVoxel> {
    let mut scratch = vec![0u32; map.len()];
    let (mut model, mut back) = (CodecModel::new(), CodecModel::new());
    let mut encoder = MapEncoder::new(map, &mut scratch, &mut model).unwrap().without_occupancy();
    let mut copy = heap_map(map.len().max(1), *map.config());
    let mut decoder = MapDecoder::new(map.len(), &mut back).without_occupancy();
    let mut chunk = vec![0u8; 1024];
    loop {
        let n = encoder.next_chunk(&mut model, &mut chunk).unwrap();
        if n == 0 {
            break;
        }
        decoder.decode_chunk(&mut back, &chunk[..n], &mut copy).unwrap();
    }
    sorted(&copy)
}

/// A copy's voxels as records (cell code, [`voxel_record`]), in code order.
fn records(map: &VecMap) -> Vec<(u64, u32)> {
    sorted(map).iter().map(|v| (crate::wire::codec::morton(v.key), voxel_record(v))).collect()
}

/// The copy holds the map as published, bit for bit (the publisher's
/// records), and that is the map decoded but for records a step apart.
fn assert_published(copy: &VecMap, published: &[ShadowEntry], map: &VecMap, what: &str) {
    let held = records(copy);
    // An update carries no occupancy: the copy holds each voxel at one hit.
    assert!(copy.iter().all(|v| voxel_record(v) == update_record(v)), "{what}: the copy holds an occupancy");
    let want: Vec<(u64, u32)> = published.iter().map(|r| (r.code, r.record)).collect();
    assert_eq!(held, want, "{what}: the copy is not the map as published");
    let truth = decoded(map);
    assert_eq!(held.len(), truth.len(), "{what}");
    for ((code, record), t) in held.iter().zip(&truth) {
        assert_eq!(*code, crate::wire::codec::morton(t.key), "{what}");
        assert!(within_step(*record, voxel_record(t)), "{what}: {record:#x} against {:#x}", voxel_record(t));
    }
}

fn sorted(map: &VecMap) -> Vec<SemanticVoxel> {
    let mut v: Vec<SemanticVoxel> = map.iter().copied().collect();
    v.sort_by_key(|v| crate::wire::codec::morton(v.key));
    v
}

/// The two robots' sides of one direction of a session.
struct Ends {
    held: Vec<ShadowEntry>,
    sent: Vec<ShadowEntry>,
    replica: Replica<crate::map::VecStorage>,
    scratch: Vec<u32>,
    out: Vec<u8>,
}

impl Ends {
    fn new() -> Self {
        Ends {
            held: vec![ShadowEntry::default(); CAPACITY],
            sent: vec![ShadowEntry::default(); CAPACITY],
            replica: Replica::new(robot_map()),
            scratch: vec![0u32; CAPACITY],
            out: vec![0u8; 64 * 1024],
        }
    }
}

#[test]
fn updates_keep_the_copy_equal_to_the_decoded_map() {
    let mut ends = Ends::new();
    let Ends { held, sent, replica, scratch, out } = &mut ends;
    let mut publisher = Publisher::new(7, &mut held[..], &mut sent[..]);
    let (mut map, mut rng) = (robot_map(), Lcg(1));
    let mut ratios = Vec::new();
    let (mut removed, mut by_rank, mut cuts) = (0, 0, 0);
    for round in 0..40 {
        drive(&mut map, round, &mut rng);
        let n = publisher.next_update(&map, scratch, out).unwrap();
        removed += publisher.counts().removed;
        let view = UpdateView::parse(&out[..n]).unwrap();
        by_rank += view.header.removals;
        let cut = view.cut.is_some();
        assert_eq!(replica.apply(&out[..n], scratch), Applied::Applied, "round {round}");
        // A cut says where the sender was: the copy knows its peer's place
        // to a 32nd of a cell (where it is, or where it last evicted).
        if cut {
            cuts += 1;
            let at = replica.peer_place().unwrap();
            let near = |c: [f32; 3]| (0..3).all(|k| (at[k] - c[k]).abs() <= map.resolution() / 64.0 + 1e-4);
            assert!(near(map.keep_centre()) || map.last_cut_centre().is_some_and(near), "round {round}: {at:?}");
        }
        publisher.on_ack(&replica.answer());
        assert_eq!(publisher.acked(), publisher.version());
        assert_published(replica.map(), publisher.published(), &map, &std::format!("round {round}"));
        // The digest kept as updates apply is the copy's, summed afresh.
        assert_eq!(replica.answer().digest, digest_of(records(replica.map()).into_iter()), "round {round}");
        if round > 0 {
            let whole = {
                let held2 = vec![ShadowEntry::default(); CAPACITY];
                let sent2 = vec![ShadowEntry::default(); CAPACITY];
                let mut fresh = Publisher::new(1, held2, sent2);
                let mut o = vec![0u8; 64 * 1024];
                fresh.next_update(&map, &mut vec![0u32; CAPACITY], &mut o).unwrap()
            };
            ratios.push(n as f32 / whole as f32);
        }
    }
    // The map filled and evicted around the moving robot; the far side of
    // its ball left the copy by the updates' cuts, not cell by cell.
    assert!(map.evicted() > 0 && map.len() > CAPACITY / 2, "{} {}", map.len(), map.evicted());
    std::println!("removed {removed}, by rank {by_rank}");
    assert!(removed > 1_000 && by_rank * 10 < removed, "removed {removed}, by rank {by_rank}");
    assert!(cuts > 10, "{cuts} cuts");
    ratios.sort_by(f32::total_cmp);
    let median = ratios[ratios.len() / 2];
    // An update is what changed, well below a whole map.
    std::println!("update / snapshot: median {median:.3}, max {:.3}", ratios[ratios.len() - 1]);
    assert!(median < 0.8, "median update / snapshot {median}");
}

/// An update bounded by a budget: no update (but the snapshot) is longer;
/// what waits is what changed farthest from the robot, changed voxels
/// before new ones; the copy is always the map as published; and once the
/// robot stops, what waited follows until the copy is the map decoded.
#[test]
fn a_budget_bounds_each_update_and_what_waits_follows() {
    const BUDGET: usize = 300;
    let mut ends = Ends::new();
    let Ends { held, sent, replica, scratch, out } = &mut ends;
    let mut publisher = Publisher::new(4, &mut held[..], &mut sent[..]);
    publisher.set_budget(Some(UpdateBudget::Bytes(BUDGET as u32)));
    let (mut map, mut rng) = (robot_map(), Lcg(3));
    let (mut deferred_new, mut deferred) = (0, 0);
    let whole_cells = |code: u64, map: &VecMap| {
        let k = crate::wire::codec::key_of(code).unwrap();
        let c = map.keep_centre();
        let r = map.resolution();
        let d = [k.x, k.y, k.z].iter().zip(c).map(|(&k, c)| ((f32::from(k) + 0.5) * r - c).powi(2)).sum::<f32>();
        libm::floorf(libm::sqrtf(d) / r)
    };
    for round in 0..80 {
        // Driving for 40 rounds, then standing still.
        if round < 40 {
            drive(&mut map, round, &mut rng);
        }
        let before: Vec<u64> = publisher.published().iter().map(|r| r.code).collect();
        let n = publisher.next_update(&map, scratch, out).unwrap();
        let counts = publisher.counts();
        assert!(round == 0 || n <= BUDGET, "round {round}: {n} bytes");
        deferred += counts.deferred;
        assert_eq!(replica.apply(&out[..n], scratch), Applied::Applied, "round {round}");
        publisher.on_ack(&replica.answer());
        let published = publisher.published();
        let want: Vec<(u64, u32)> = published.iter().map(|r| (r.code, r.record)).collect();
        assert_eq!(records(replica.map()), want, "round {round}: the copy is not the map as published");
        // The cells the map has and the copy lacks waited; those the
        // update sent new were nearer, by whole cells, and no changed
        // voxel went while a new one waited.
        let codes: std::collections::BTreeSet<u64> = published.iter().map(|r| r.code).collect();
        let waiting: Vec<u64> =
            map.iter().map(|v| crate::wire::codec::morton(v.key)).filter(|c| !codes.contains(c)).collect();
        let sent_new: Vec<u64> = codes.iter().copied().filter(|c| before.binary_search(c).is_err()).collect();
        if round > 0 && !waiting.is_empty() {
            deferred_new += 1;
            assert_eq!(counts.changed, 0, "round {round}: a changed voxel sent while a new one waited");
            let nearest_waiting = waiting.iter().map(|&c| whole_cells(c, &map)).fold(f32::INFINITY, f32::min);
            let farthest_sent = sent_new.iter().map(|&c| whole_cells(c, &map)).fold(0.0, f32::max);
            assert!(farthest_sent <= nearest_waiting + 1.0, "round {round}: {farthest_sent} {nearest_waiting}");
        }
    }
    assert!(
        deferred_new > 5 && deferred > 1_000,
        "the budget held back {deferred} ({deferred_new} rounds with new ones)"
    );
    // Standing still, everything that waited went: the copy is the map.
    assert_eq!(publisher.counts().deferred, 0);
    assert_published(replica.map(), publisher.published(), &map, "after the robot stopped");
}

/// A budget that is a share of the map: each update and its answer
/// within that share of the map sent whole (measured as a fresh publisher
/// sends it), the copy always the map as published, and some rounds
/// bounded by it; once the robot stops, the copy is the map.
#[test]
fn a_share_of_the_map_bounds_each_update_with_its_answer() {
    const PER_MILLE: u16 = 150;
    let mut ends = Ends::new();
    let Ends { held, sent, replica, scratch, out } = &mut ends;
    let mut publisher = Publisher::new(6, &mut held[..], &mut sent[..]);
    publisher.set_budget(Some(UpdateBudget::PerMille(PER_MILLE)));
    let (mut map, mut rng) = (robot_map(), Lcg(5));
    let (mut bounded, mut most) = (0, 0.0f64);
    for round in 0..60 {
        if round < 40 {
            drive(&mut map, round, &mut rng);
        }
        let whole = {
            let (mut h, mut s) = (vec![ShadowEntry::EMPTY; CAPACITY], vec![ShadowEntry::EMPTY; CAPACITY]);
            let mut fresh = Publisher::new(6, &mut h[..], &mut s[..]);
            let mut o = vec![0u8; out.len()];
            fresh.next_update(&map, scratch, &mut o).unwrap()
        };
        let n = publisher.next_update(&map, scratch, out).unwrap();
        let counts = publisher.counts();
        assert_eq!(replica.apply(&out[..n], scratch), Applied::Applied, "round {round}");
        publisher.on_ack(&replica.answer());
        if round > 0 {
            let share = (n + crate::wire::update::ACK_BYTES) as f64 / whole as f64;
            assert!(
                n + crate::wire::update::ACK_BYTES <= whole * usize::from(PER_MILLE) / 1000,
                "round {round}: {n} of {whole}"
            );
            most = most.max(share);
            bounded += usize::from(counts.deferred > 0);
        }
        let want: Vec<(u64, u32)> = publisher.published().iter().map(|r| (r.code, r.record)).collect();
        assert_eq!(records(replica.map()), want, "round {round}: the copy is not the map as published");
    }
    assert!(bounded > 5 && most > 0.14, "{bounded} rounds bounded, the largest share {most}");
    assert_eq!(publisher.counts().deferred, 0);
    assert_published(replica.map(), publisher.published(), &map, "after the robot stopped");
}

/// An update's voxels are coded with the codec model the update to its
/// base left (a snapshot: a fresh one): a receiver that kept that model
/// reads them, one with a fresh model does not, and the models follow a
/// lost update (the next is coded from the acknowledged one's).
#[test]
fn an_update_is_coded_with_the_model_its_base_left() {
    let mut ends = Ends::new();
    let Ends { held, sent, replica, scratch, out } = &mut ends;
    let mut publisher = Publisher::new(5, &mut held[..], &mut sent[..]);
    let (mut map, mut rng) = (robot_map(), Lcg(8));
    // The receiver's model, kept beside the replica's by decoding each
    // update applied.
    let mut mirror = CodecModel::new();
    let upserts = |bytes: &[u8], m: &mut CodecModel| {
        let mut sink = heap_map(CAPACITY, map_config());
        UpdateView::parse(bytes).unwrap().decode_upserts(m, &mut sink).map(|()| records(&sink))
    };
    for round in 0..12 {
        drive(&mut map, round, &mut rng);
        let n = publisher.next_update(&map, scratch, out).unwrap();
        if round == 8 {
            // Lost: the next update is from the acknowledged version, and
            // coded from its model.
            continue;
        }
        assert_eq!(replica.apply(&out[..n], scratch), Applied::Applied, "round {round}");
        publisher.on_ack(&replica.answer());
        let mine = upserts(&out[..n], &mut mirror).unwrap();
        if round > 0 {
            let header = UpdateView::parse(&out[..n]).unwrap().header;
            assert!(header.base != 0 && header.upserts > 50, "round {round}: {header:?}");
            let fresh = upserts(&out[..n], &mut CodecModel::new());
            assert!(fresh.as_ref() != Ok(&mine), "round {round}: read with a fresh model");
        }
        assert_published(replica.map(), publisher.published(), &map, &std::format!("round {round}"));
    }
}

/// Updates and answers lost, repeated and damaged: the copy is never
/// taken as the peer's map unless it is one, and it is repaired (resent
/// from what was held, or a snapshot).
#[test]
fn lost_repeated_and_damaged_updates_are_repaired() {
    let mut ends = Ends::new();
    let Ends { held, sent, replica, scratch, out } = &mut ends;
    let mut publisher = Publisher::new(3, &mut held[..], &mut sent[..]);
    let (mut map, mut rng, mut faults) = (robot_map(), Lcg(2), Lcg(99));
    let mut seen = std::collections::BTreeMap::new();
    let mut in_sync_after_clean_round = 0;
    for round in 0..120 {
        drive(&mut map, round % 60, &mut rng);
        let n = publisher.next_update(&map, scratch, out).unwrap();
        let mut update = out[..n].to_vec();
        let fault = faults.unit();
        let clean = round % 10 == 9;
        let deliveries = if clean {
            1
        } else if fault < 0.2 {
            0
        } else if fault < 0.3 {
            2
        } else {
            if fault < 0.45 {
                let at = (faults.unit() * n as f32) as usize % n;
                update[at] ^= 1 + (faults.unit() * 254.0) as u8;
            }
            1
        };
        for _ in 0..deliveries {
            let what = replica.apply(&update, scratch);
            *seen.entry(std::format!("{what:?}")).or_insert(0) += 1;
            // Whatever became of it, the digest answered is the copy's.
            assert_eq!(replica.answer().digest, digest_of(records(replica.map()).into_iter()), "round {round}");
            if what == Applied::Applied || what == Applied::Repeated {
                assert_published(replica.map(), publisher.published(), &map, &std::format!("round {round}: {what:?}"));
            }
            let answer = replica.answer();
            // An answer may be lost too (or arrive damaged and be dropped).
            if clean || faults.unit() > 0.1 {
                let bytes = answer.encode();
                publisher.on_ack(&UpdateAck::decode(&bytes).unwrap());
            }
        }
        if clean && replica.version() == publisher.version() {
            in_sync_after_clean_round += 1;
        }
        if replica.version() != 0 && replica.version() == publisher.version() {
            assert_published(replica.map(), publisher.published(), &map, &std::format!("round {round}"));
        }
    }
    // Every kind of trouble happened, and the clean rounds found the copy
    // repaired (an update lost before a clean round is resent in it).
    for kind in ["Applied", "Repeated", "Refused(Checksum)"] {
        assert!(seen.contains_key(kind), "{kind} never seen: {seen:?}");
    }
    std::println!("{seen:?}, {in_sync_after_clean_round} of 12 clean rounds in sync");
    assert!(in_sync_after_clean_round >= 10, "{in_sync_after_clean_round} of 12 clean rounds in sync: {seen:?}");
}

#[test]
fn a_restarted_peer_is_noticed_and_sends_a_snapshot() {
    let mut ends = Ends::new();
    let Ends { held, sent, replica, scratch, out } = &mut ends;
    let (mut map, mut rng) = (robot_map(), Lcg(5));
    {
        let mut first = Publisher::new(1, &mut held[..], &mut sent[..]);
        for round in 0..3 {
            drive(&mut map, round, &mut rng);
            let n = first.next_update(&map, scratch, out).unwrap();
            assert_eq!(replica.apply(&out[..n], scratch), Applied::Applied);
            first.on_ack(&replica.answer());
        }
    }
    // The peer restarts (another epoch) and, wrongly, sends a delta first.
    let mut forged = out.clone();
    let held2 = vec![ShadowEntry::default(); CAPACITY];
    let sent2 = vec![ShadowEntry::default(); CAPACITY];
    let mut second = Publisher::new(2, held2, sent2);
    drive(&mut map, 3, &mut rng);
    let n = second.next_update(&map, scratch, &mut forged).unwrap();
    assert_eq!(UpdateView::parse(&forged[..n]).unwrap().header.base, 0, "a new publisher starts with a snapshot");
    // A delta of the new epoch (base 5: the first varint after the fixed
    // fields) is refused as a restart.
    forged[crate::wire::update::UPDATE_HEADER] = 5;
    let crc = crate::wire::crc32(&forged[..n - 4]);
    forged[n - 4..n].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(replica.apply(&forged[..n], scratch), Applied::Restarted);
    assert_eq!(replica.answer().version, 0);
    second.on_ack(&replica.answer());
    let n = second.next_update(&map, scratch, out).unwrap();
    assert_eq!(replica.apply(&out[..n], scratch), Applied::Applied);
    assert_eq!(sorted(replica.map()), decoded(&map));
    second.on_ack(&replica.answer());
    assert_eq!(second.acked(), second.version());
    // An answer of the old epoch is ignored by the new publisher.
    second.on_ack(&UpdateAck { epoch: 1, version: 0, digest: 0, capacity: 10 });
    assert_eq!(second.acked(), second.version(), "still acknowledged");
}

/// Forged updates (bytes changed, the CRC made to match), applied to a
/// copy at their base: never a panic, and never a copy taken as the
/// peer's map that is not one.
#[test]
fn forged_updates_never_pass_as_the_map() {
    let mut ends = Ends::new();
    let Ends { held, sent, scratch, out, .. } = &mut ends;
    let mut publisher = Publisher::new(9, &mut held[..], &mut sent[..]);
    let (mut map, mut rng, mut forge) = (robot_map(), Lcg(3), Lcg(4));
    let (mut history, mut outcomes): (Vec<Vec<u8>>, std::collections::BTreeMap<_, usize>) = Default::default();
    for round in 0..7 {
        drive(&mut map, round, &mut rng);
        let n = publisher.next_update(&map, scratch, out).unwrap();
        let truth: Vec<(u64, u32)> = publisher.published().iter().map(|r| (r.code, r.record)).collect();
        for _ in 0..40 {
            let mut bytes = out[..n].to_vec();
            for _ in 0..1 + (forge.unit() * 4.0) as usize {
                let at = (forge.unit() * (n - 4) as f32) as usize;
                bytes[at] = (forge.unit() * 256.0) as u8;
            }
            if forge.unit() < 0.2 {
                bytes.truncate((forge.unit() * n as f32) as usize);
            }
            if bytes.len() > 4 {
                let m = bytes.len() - 4;
                let crc = crate::wire::crc32(&bytes[..m]);
                bytes[m..].copy_from_slice(&crc.to_le_bytes());
            }
            let mut copy = Replica::new(robot_map());
            for earlier in &history {
                assert_eq!(copy.apply(earlier, scratch), Applied::Applied);
            }
            let what = copy.apply(&bytes, scratch);
            *outcomes.entry(std::format!("{what:?}")).or_default() += 1;
            if what == Applied::Applied {
                assert_eq!(records(copy.map()), truth, "a forged update made another map");
            }
        }
        history.push(out[..n].to_vec());
        let mut copy = Replica::new(robot_map());
        for update in &history {
            assert_eq!(copy.apply(update, scratch), Applied::Applied);
        }
        publisher.on_ack(&copy.answer());
    }
    std::println!("forged updates: {outcomes:?}");
    assert!(outcomes.len() >= 3, "{outcomes:?}");
    // The map evicted: some of the updates forged named cells by a cut.
    assert!(history.iter().any(|u| UpdateView::parse(u).unwrap().cut.is_some()), "no update with a cut");
}

/// A peer that holds fewer voxels than the map (a smaller board) is sent
/// the part that fits, round after round: its copy is, bit for bit, the
/// decoded map of the voxels nearest where the robot is, never more than
/// it said it holds (from its first answer, sent before any update); the
/// digests are that part's.
#[test]
fn a_smaller_peer_is_sent_the_part_of_the_map_that_fits() {
    const SMALL: usize = 900;
    let mut ends = Ends::new();
    let config = *robot_map().config();
    ends.replica = Replica::new(heap_map(SMALL, config));
    let Ends { held, sent, replica, scratch, out } = &mut ends;
    let mut publisher = Publisher::new(2, &mut held[..], &mut sent[..]);
    let (mut map, mut rng) = (robot_map(), Lcg(9));
    // The copy's first answer, before any update, says what it holds.
    publisher.on_ack(&replica.answer());
    for round in 0..12 {
        drive(&mut map, round, &mut rng);
        assert!(map.len() > SMALL);
        let n = publisher.next_update(&map, scratch, out).unwrap();
        let applied = replica.apply(&out[..n], scratch);
        publisher.on_ack(&replica.answer());
        assert_eq!(applied, Applied::Applied, "round {round}");
        assert_eq!(replica.map().len(), SMALL.min(map.len()), "round {round}");
        let mut part = vec![0u32; map.len()];
        let FullPolicy::EvictFarthest { anchor } = map.config().when_full else { unreachable!() };
        let k = map.nearest(anchor, SMALL, &mut part);
        let mut nearest = heap_map(k, config);
        for &i in &part[..k] {
            nearest.upsert_voxel(*map.voxel(i as usize).unwrap()).unwrap();
        }
        assert_published(replica.map(), publisher.published(), &nearest, &std::format!("round {round}"));
    }
}

/// A voxel nudged within the deadband (a step of the confidence, two of
/// an axis of the mean) is not resent (the copy keeps the record it has);
/// moved further, or relabelled, it is.
#[test]
fn a_voxel_is_resent_only_when_it_moved_beyond_the_deadband() {
    let mut ends = Ends::new();
    let Ends { held, sent, replica, scratch, out } = &mut ends;
    let mut publisher = Publisher::new(4, &mut held[..], &mut sent[..]);
    let (mut map, mut rng) = (robot_map(), Lcg(21));
    drive(&mut map, 0, &mut rng);
    let v = *map.voxel(0).unwrap();
    let with_x = |x: u16| {
        let m = v.mean_raw();
        SemanticVoxel::from_parts(v.key, [x, m[1], m[2]], v.occupancy_raw(), v.hits(), v.labels)
    };
    let mut exchange = |map: &VecMap, publisher: &mut Publisher<&mut [ShadowEntry]>| {
        let n = publisher.next_update(map, scratch, out).unwrap();
        assert_eq!(replica.apply(&out[..n], scratch), Applied::Applied);
        publisher.on_ack(&replica.answer());
        assert_published(replica.map(), publisher.published(), map, "exchange");
        (publisher.counts().changed, records(replica.map()))
    };
    // Step 0 of the mean's x, then steps 1 and 2: not resent, the copy
    // keeps step 0.
    map.upsert_voxel(with_x(0x1000)).unwrap();
    let (_, before) = exchange(&map, &mut publisher);
    for x in [0x5000, 0x9000] {
        map.upsert_voxel(with_x(x)).unwrap();
        let (changed, after) = exchange(&map, &mut publisher);
        assert_eq!((changed, &after), (0, &before), "a nudge within the deadband was resent: {x:#x}");
    }
    // Step 3: three from what the copy holds: resent.
    map.upsert_voxel(with_x(0xD000)).unwrap();
    let (changed, after) = exchange(&map, &mut publisher);
    assert_eq!(changed, 1);
    let code = crate::wire::codec::morton(v.key);
    let held = after.iter().find(|r| r.0 == code).unwrap().1;
    assert_eq!(held, update_record(&with_x(0xD000)));
    // Relabelled: resent, however little else moved.
    let mut labels = crate::map::LabelDistribution::EMPTY;
    let other = if v.class() == Some(Class::Road) { Class::Building } else { Class::Road };
    labels.observe(other, 1000);
    let m = with_x(0xD000).mean_raw();
    map.upsert_voxel(SemanticVoxel::from_parts(v.key, m, v.occupancy_raw(), v.hits(), labels)).unwrap();
    assert_eq!(exchange(&map, &mut publisher).0, 1);
}

mod history;
mod smoothing;
mod tracking;
mod walk;

/// A broadcast (a ROS 2 node's updates over DDS): no answers, each update
/// taken as delivered, a snapshot every few. A follower that saw every
/// update holds the map as published after each; one that missed an update
/// is out of step until the next snapshot, and holds the map from there;
/// one that joins late starts from the last snapshot and the updates after
/// it.
#[test]
fn a_broadcast_with_snapshots_lets_followers_catch_up() {
    let mut held = vec![ShadowEntry::default(); CAPACITY];
    let mut sent = vec![ShadowEntry::default(); CAPACITY];
    let mut publisher = Publisher::new(3, &mut held[..], &mut sent[..]);
    let (mut map, mut rng) = (robot_map(), Lcg(5));
    let mut scratch = vec![0u32; 2 * CAPACITY];
    let mut out = vec![0u8; 64 * 1024];
    let (mut all, mut lossy) = (Replica::new(robot_map()), Replica::new(robot_map()));
    let mut late: Option<Replica<crate::map::VecStorage>> = None;
    let mut log: Vec<Vec<u8>> = Vec::new();
    let mut last_snapshot = 0usize;
    for round in 0..30 {
        drive(&mut map, round, &mut rng);
        if round % 8 == 0 {
            publisher.snapshot_next();
        }
        let n = publisher.next_update(&map, &mut scratch, &mut out).unwrap();
        publisher.delivered();
        assert_eq!(publisher.acked(), publisher.version(), "round {round}");
        let bytes = out[..n].to_vec();
        let snapshot = publisher.counts().snapshot;
        assert_eq!(snapshot, round % 8 == 0, "round {round}");
        if snapshot {
            last_snapshot = log.len();
        }
        log.push(bytes.clone());
        assert_eq!(all.apply(&bytes, &mut scratch), Applied::Applied, "round {round}");
        assert_published(all.map(), publisher.published(), &map, &std::format!("round {round}"));
        // The lossy follower misses round 3's update.
        let lossy_got = if round == 3 { None } else { Some(lossy.apply(&bytes, &mut scratch)) };
        match round {
            3 => {}
            4..=7 => assert_eq!(lossy_got, Some(Applied::OutOfStep), "round {round}"),
            _ => assert_eq!(lossy_got, Some(Applied::Applied), "round {round}"),
        }
        if round >= 8 {
            assert_eq!(records(lossy.map()), records(all.map()), "round {round}");
        }
        // The late one joins at round 20: the last snapshot, then the
        // updates after it, as a transient-local history replays them.
        if round == 20 {
            let mut r = Replica::new(robot_map());
            for b in &log[last_snapshot..] {
                assert_eq!(r.apply(b, &mut scratch), Applied::Applied);
            }
            late = Some(r);
        } else if let Some(r) = late.as_mut() {
            assert_eq!(r.apply(&bytes, &mut scratch), Applied::Applied, "round {round}");
        }
    }
    let late = late.unwrap();
    assert_eq!(records(late.map()), records(all.map()));
    assert_eq!(late.answer().digest, all.answer().digest);
}
