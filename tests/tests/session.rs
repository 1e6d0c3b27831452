//! `cosem session`: robots that keep driving, on real data and on data the
//! project makes itself.

use cosem_tests::{cosem_err, cosem_ok, cosem_usage_err, real_data, synth};
use serde_json::Value;

/// The JSON lines of a session: the records, and the summary.
fn session(args: &[&str]) -> (Vec<Value>, Value) {
    let mut all = vec!["session", "--json"];
    all.extend_from_slice(args);
    let out = cosem_ok(&all);
    let mut lines: Vec<Value> = out.lines().map(|l| serde_json::from_str(l).expect("a JSON line")).collect();
    let summary = lines.pop().expect("a summary line");
    (lines, summary["summary"].clone())
}

/// Estimates Converged within the conventions' strict thresholds.
fn right(records: &[Value]) -> usize {
    let strict = |r: &&Value| r["e_t"].as_f64().unwrap() < 0.5 && r["e_r"].as_f64().unwrap() < 1.0;
    records.iter().filter(|r| r["status"] == "Converged").filter(strict).count()
}

fn check_record_fields(r: &Value) {
    for key in [
        "round",
        "robot",
        "peer",
        "status",
        "kind",
        "fix",
        "adopted",
        "contested",
        "disputed",
        "walked",
        "bytes_sent",
        "seconds",
        "update",
        "update_deferred",
    ] {
        assert!(!r[key].is_null(), "{key} missing: {r}");
    }
    let status = r["status"].as_str().unwrap();
    assert!(["Converged", "NotConverged", "Degenerate", "NoOverlap"].contains(&status), "{r}");
    // A fix the robot's history contradicts is never reported Converged.
    assert!(r["contested"] == false || status != "Converged", "{r}");
    // Nor one the peer's latest estimate disputes.
    assert!(r["disputed"] == false || status != "Converged", "{r}");
    // Nor any while the two robots' odometry walks too much.
    assert!(r["walked"] == false || status != "Converged", "{r}");
    assert!(["prior-free", "tracking"].contains(&r["kind"].as_str().unwrap()), "{r}");
    if let Some(t) = r["T_own_peer"].as_array() {
        assert_eq!(t.len(), 12, "3x4 row-major: {r}");
    }
    if !r["e_t"].is_null() {
        assert!(r["e_t_origin"].as_f64().is_some_and(|m| m >= 0.0), "an error at the odometry origin: {r}");
        for key in ["e_t_local", "e_r_local"] {
            assert!(r[key].as_f64().is_some_and(|m| m >= 0.0), "{key}: {r}");
        }
    }
}

/// kitti00, robot A on frames 0:10 and B on 5:10: about five rounds, no
/// parting; every estimate right, tracked after the first, and Converged
/// from the first round (both robots find the fix in it, and each
/// confirms its own with the peer's estimate of that round, carried by the
/// peer's answer).
#[test]
fn kitti00_robots_are_tracked_round_after_round() {
    let Some(d) = real_data("kitti00") else { return };
    let (a, b) = (format!("{}:0:10", d.display()), format!("{}:5:10", d.display()));
    let (records, summary) = session(&["--robot", &a, "--robot", &b]);
    assert_eq!(records.len(), 2 * 5, "5 rounds, both directions");
    for r in &records {
        check_record_fields(r);
        let first = r["round"] == 0;
        assert_eq!(r["status"], "Converged", "{r}");
        assert_eq!((&r["fix"], &r["confirmed"]), (&"held".into(), &true.into()), "{r}");
        assert!(r["e_t"].as_f64().unwrap() < 0.5 && r["e_r"].as_f64().unwrap() < 1.0, "{r}");
        assert_eq!(r["kind"], if first { "prior-free" } else { "tracking" }, "{r}");
        assert!(r["overlap_true"].as_f64().unwrap() > 0.3, "{r}");
    }
    assert_eq!(summary["schema_version"], 11);
    assert_eq!(summary["wrong_converged"], 0, "{summary}");
    assert_eq!(summary["availability"], 1.0, "{summary}");
    assert_eq!(summary["first_fix_rounds"], 0, "{summary}");
    // After the first round, updates are what changed: less than a whole map.
    let [p50, _, max] = [0, 1, 2].map(|k| summary["update_bytes_ratio"][k].as_f64().unwrap());
    assert!(p50 < 0.8 && max < 1.0, "{summary}");
}

/// The project's own street, with drift: robots that meet are placed right
/// (against the drifted truth); robots 40 m apart are never placed.
#[test]
fn synthetic_robots_meet_under_drift_and_apart_are_never_placed() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("street");
    synth(&s, 60, 1);
    let seq = s.display().to_string();
    let (records, summary) = session(&[
        "--robot",
        &format!("{seq}:0:18"),
        "--robot",
        &format!("{seq}:10:28"),
        "--drift",
        "1%,0.5",
        "--seed",
        "4",
    ]);
    records.iter().for_each(check_record_fields);
    assert_eq!(summary["wrong_converged"], 0, "{summary}");
    let right = right(&records);
    assert!(right >= records.len() * 3 / 4, "{right} of {} right", records.len());
    // The truth moves with the drift: the estimates of the last round are
    // not those of the first.
    let t = |r: &Value| r["T_own_peer"][3].as_f64().unwrap();
    assert!((t(&records[0]) - t(records.last().unwrap())).abs() > 1e-3);
    let (apart, summary) =
        session(&["--robot", &format!("{seq}:0:8"), "--robot", &format!("{seq}:50:58"), "--drift", "1%,0.5"]);
    assert!(apart.iter().all(|r| r["status"] != "Converged"), "{apart:?}");
    assert_eq!(summary["meetings"], 0, "{summary}");
}

/// `--one-shot`, the baseline: every round the whole map again and a
/// prior-free match, nothing carried over; on the same street and drift as
/// above, the same robots are placed.
#[test]
fn one_shot_rounds_send_whole_maps_and_search_prior_free() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("street");
    synth(&s, 30, 1);
    let seq = s.display().to_string();
    let args = ["--robot", &format!("{seq}:0:18"), "--robot", &format!("{seq}:10:28"), "--drift", "1%,0.5"];
    let (tracked, _) = session(&args);
    let (records, summary) = session(&[&args[..], &["--one-shot"]].concat());
    assert_eq!(records.len(), tracked.len());
    for r in &records {
        check_record_fields(r);
        assert_eq!(r["kind"], "prior-free", "{r}");
        assert!(r["update_new"].as_u64().unwrap() > 0, "{r}");
        assert_eq!(r["update_changed"], 0, "a fresh copy: every voxel new: {r}");
        let ratio = r["update_ratio"].as_f64().unwrap();
        assert!((1.0..1.01).contains(&ratio), "the whole map (and the answer) every round: {r}");
    }
    // Tracked rounds after the first send less than the whole map.
    let later = |rs: &[Value]| rs.iter().skip(2).map(|r| r["bytes_sent"].as_u64().unwrap()).sum::<u64>();
    assert!(later(&tracked) < later(&records), "tracked updates are deltas");
    assert!(summary["tracking_cost_ratio"].is_null(), "no tracking round: {summary}");
    assert_eq!(summary["wrong_converged"], 0, "{summary}");
    assert!(right(&records) >= records.len() / 2, "{summary}");
}

/// `--line lossy=P`: each pair's updates traded over a simulated line of
/// `--baud` by the boards' courier. On a fast clean line every update is
/// across within its round: the estimates are those of the session without
/// a line. On a slow one that damages bytes some rounds find the peer's
/// update still on the line (the robot estimates on the copy it held), and
/// the line carries more bytes than the updates hold, in more time.
#[test]
fn updates_cross_a_line_in_their_round_or_later() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("street");
    synth(&s, 28, 1);
    let seq = s.display().to_string();
    let args = ["--robot", &format!("{seq}:0:18"), "--robot", &format!("{seq}:10:28"), "--drift", "1%,0.5"];
    let (handed, plain) = session(&args);
    assert!(plain["line_bytes"].is_null() && handed.iter().all(|r| r["line_ms"].is_null()), "{plain}");
    let strip = |r: &Value| {
        let mut r = r.clone();
        for k in ["seconds", "line_bytes", "line_ms"] {
            r.as_object_mut().unwrap().remove(k);
        }
        r
    };
    let (fast, summary) = session(&[&args[..], &["--line", "lossy=0", "--baud", "2000000"]].concat());
    assert_eq!(fast.len(), handed.len());
    for (r, h) in fast.iter().zip(&handed) {
        assert_eq!(strip(r), strip(h), "a fast clean line: the same estimate as without a line");
        assert!(r["line_bytes"].as_u64().unwrap() > 0 && r["line_ms"].as_u64().unwrap() <= 200, "{r}");
    }
    assert!(summary["line_bytes"].as_u64().unwrap() > summary["bytes"].as_u64().unwrap(), "frames, acks: {summary}");
    assert_eq!(summary["line_late"], 0, "{summary}");
    let (slow, summary) = session(&[&args[..], &["--line", "lossy=0.02"]].concat());
    assert_eq!(slow.len(), handed.len());
    slow.iter().for_each(check_record_fields);
    let waiting = slow.iter().filter(|r| r["update"] == "OnTheLine").count();
    assert!(waiting > 0, "a slow damaging line leaves updates on it past their round");
    assert!(slow.iter().filter(|r| r["update"] == "OnTheLine").all(|r| r["line_ms"].is_null() && r["bytes_sent"] == 0));
    let late = slow.iter().filter(|r| r["robot"] == 1 && r["line_ms"].as_u64().is_some_and(|ms| ms > 200)).count();
    assert!(late > 0 && summary["line_late"].as_u64().unwrap() as usize == late, "{summary}");
    assert!(summary["line_ms"][1].as_f64().unwrap() > 200.0, "{summary}");
    let e = cosem_err(&[&["session"][..], &args[..], &["--line", "silent"]].concat());
    assert!(e.contains("--line silent"), "{e}");
    let e = cosem_err(&[&["session"][..], &args[..], &["--line", "lossy=0", "--one-shot"]].concat());
    assert!(e.contains("--one-shot"), "{e}");
}

/// Robots of different capacities: the larger sends the smaller the part
/// of its map nearest itself, never more voxels than the smaller holds.
#[test]
fn a_robot_that_holds_less_is_sent_the_part_that_fits() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("street");
    synth(&s, 18, 1);
    let seq = s.display().to_string();
    let small = 1_200;
    let (records, _) = session(&[
        "--robot",
        &format!("{seq}:0:12"),
        "--robot",
        &format!("{seq}:6:18"),
        "--capacity",
        &format!("6000,{small}"),
    ]);
    records.iter().for_each(check_record_fields);
    let into_small: Vec<&Value> = records.iter().filter(|r| r["robot"] == 1).collect();
    let first = into_small[0];
    assert_eq!(first["update"], "Applied", "{first}");
    assert_eq!(first["update_new"], small, "the first update is the part that fits: {first}");
    for r in &into_small {
        let upserts = r["update_new"].as_u64().unwrap() + r["update_changed"].as_u64().unwrap();
        assert!(upserts <= small, "{r}");
        assert_eq!(r["update"], "Applied", "{r}");
    }
    let e = cosem_usage_err(&["session", "--capacity", "8000,20"]);
    assert!(e.contains("--capacity") && e.contains("8000,20"), "{e}");
    let e = cosem_err(&[
        "session",
        "--robot",
        &format!("{seq}:0:4"),
        "--robot",
        &format!("{seq}:4:8"),
        "--capacity",
        "900,900,900",
    ]);
    assert!(e.contains("--capacity") && e.contains("one per robot"), "{e}");
}

#[test]
fn session_arguments_are_checked() {
    let e = cosem_usage_err(&["session", "--robot", "x:0:5", "--robot", "y:0:5", "--drift", "70%,1"]);
    assert!(e.contains("--drift") && e.contains("70%,1"), "{e}");
    let e = cosem_usage_err(&["session", "--robot", "x:0:5", "--robot", "y:0:5", "--every", "0"]);
    assert!(e.contains("--every"), "{e}");
    // A slip after the last round would never happen (and be reported
    // caught at once): refused, naming the session's rounds.
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("street");
    synth(&s, 12, 1);
    let seq = s.display().to_string();
    let (a, b) = (format!("{seq}:0:8"), format!("{seq}:4:12"));
    let e = cosem_err(&["session", "--robot", &a, "--robot", &b, "--slip", "1,4"]);
    assert!(e.contains("round 4") && e.contains("has 4 rounds"), "{e}");
    for (flag, bad) in [("--line", "lossy=2"), ("--line", "fuzzy"), ("--baud", "0"), ("--baud", "fast")] {
        let e = cosem_usage_err(&["session", "--robot", "x:0:5", "--robot", "y:0:5", flag, bad]);
        assert!(e.contains(flag) && e.contains(bad), "{e}");
    }
    let e = cosem_err(&["session", "--robot", &a, "--robot", &b, "--on-board", "--update-budget", "15%"]);
    assert!(e.contains("--update-budget") && e.contains("bytes"), "{e}");
    for budget in ["10", "0", "lots", "0%", "0.04%", "101%", "NaN%", "%"] {
        let e = cosem_usage_err(&["session", "--robot", "x:0:5", "--robot", "y:0:5", "--update-budget", budget]);
        assert!(e.contains("--update-budget") && e.contains(budget), "{e}");
    }
}

/// The built-in town: robots 0 and 1 start out of sight of each other (no
/// overlap), meet at a corner after 80 m and are placed right there;
/// robot folders share one world (`world.txt`), so the truth is known.
#[test]
fn town_robots_start_apart_and_meet() {
    let dir = tempfile::tempdir().unwrap();
    let town = dir.path().join("town");
    let t = town.display().to_string();
    cosem_ok(&["synth", "--town", "--out", &t, "--frames", "100", "--seg", "none", "--seed", "3"]);
    for i in 0..2 {
        let world = std::fs::read_to_string(town.join(format!("robot_{i}/world.txt"))).unwrap();
        assert!(world.starts_with("cosem town: seed 3"), "{world}");
    }
    let (records, summary) = session(&[
        "--robot",
        &format!("{t}/robot_0:0:100"),
        "--robot",
        &format!("{t}/robot_1:0:100"),
        "--drift",
        "1%,0.5",
        "--seed",
        "3",
    ]);
    records.iter().for_each(check_record_fields);
    assert!(records[0]["overlap_true"].as_f64().unwrap() < 0.05, "{}", records[0]);
    assert!(records.iter().take(20).all(|r| r["status"] != "Converged"), "no fix before they meet");
    assert!(summary["meetings"].as_u64().unwrap() >= 1, "{summary}");
    let right = right(&records);
    assert!(right >= 5, "{right} right estimates: {summary}");
    assert!(summary["availability"].as_f64().unwrap() >= 0.5, "{summary}");
    // After the first sync every update and its answer are within the
    // default budget, 15% of the map sent whole, and some rounds held part
    // back.
    let synced: Vec<&Value> = records.iter().filter(|r| !r["update_ratio"].is_null()).collect();
    assert!(synced.iter().all(|r| r["update_ratio"].as_f64().unwrap() <= 0.15), "over the budget");
    assert!(synced.iter().any(|r| r["update_deferred"].as_u64().unwrap() > 0), "the budget never bound");
}

/// Under drift the truth moves along the maps: an estimate can be right
/// where the robots met and still miss the strict threshold at the
/// odometry origins, by its rotation error times the distance (town seed
/// 1, before tracking from the finest level: 0.38 degrees at about 80 m).
/// Every Converged estimate is right at the meeting place (`e_t`); the
/// summary counts both.
#[test]
fn under_drift_estimates_are_right_where_the_robots_met() {
    let dir = tempfile::tempdir().unwrap();
    let town = dir.path().join("town");
    let t = town.display().to_string();
    cosem_ok(&["synth", "--town", "--out", &t, "--frames", "130", "--seg", "none", "--seed", "1"]);
    let robot = |i: usize| format!("{t}/robot_{i}:0:130");
    let (records, summary) = session(&["--robot", &robot(0), "--robot", &robot(1), "--drift", "1%,0.5"]);
    records.iter().for_each(check_record_fields);
    let converged: Vec<&Value> = records.iter().filter(|r| r["status"] == "Converged").collect();
    assert!(converged.len() >= 20, "{summary}");
    for r in &converged {
        assert!(r["e_t"].as_f64().unwrap() < 0.5 && r["e_r"].as_f64().unwrap() < 1.0, "{r}");
    }
    assert_eq!(summary["wrong_converged"], 0, "{summary}");
    // Each robot measures its odometry's walk, and at the benchmark's
    // drift the pair's is under the limit: nothing is withheld for it.
    assert!(records.iter().filter(|r| r["round"].as_u64().unwrap() >= 10).all(|r| r["walk"].as_f64().is_some()));
    assert!(records.iter().all(|r| r["walked"] == false), "{summary}");
    // The origins' metric counts what is wrong at the origins (with the
    // fix tracked from the finest level, none on this town).
    let at_origin = converged.iter().filter(|r| r["e_t_origin"].as_f64().unwrap() >= 0.5).count();
    assert_eq!(summary["wrong_at_origin"].as_u64(), Some(at_origin as u64), "{summary}");
    for r in converged.iter().filter(|r| r["e_t_origin"].as_f64().unwrap() >= 0.5) {
        // The lever arm: the rotation error times the distance from the
        // odometry origin to the meeting place (tens of metres).
        let lever = r["e_t_origin"].as_f64().unwrap() / r["e_r"].as_f64().unwrap().to_radians();
        assert!(lever > 30.0, "{r}");
    }
    // Robots that start together (both at frame 82, at the first meeting)
    // part from their first fix: it explains most of both maps, so it is
    // not contested as its overlap falls (7 of 18 records were, when a
    // first fix had to grow). Every record in the meeting is right and
    // Converged, from round 0.
    let from = |i: usize| format!("{t}/robot_{i}:82:100");
    let (records, summary) = session(&["--robot", &from(0), "--robot", &from(1), "--drift", "1%,0.5"]);
    assert!(records.iter().all(|r| r["contested"] == false), "{summary}");
    let meeting: Vec<&Value> = records.iter().filter(|r| r["overlap_true"].as_f64().unwrap() >= 0.3).collect();
    assert!(meeting.len() >= 14, "{summary}");
    assert!(meeting.iter().all(|r| r["status"] == "Converged"), "{summary}");
    assert_eq!(summary["wrong_converged"], 0, "{summary}");
}

/// Under a heading walk four times the benchmark's (`--drift 2%,2`, the
/// built-in town, seed 1), a rigid transform between the maps cannot
/// follow the walk at the one pair of scans the truth is taken at: of the
/// estimates that pass (63 when measured) 19 miss the strict thresholds,
/// though against the truth as the maps hold it about that pair (each
/// robot's frame averaged over its scans within the crop) every one is
/// right. Each robot measures its own walk (its scans against its map
/// before they are fused, `walk`), the two together are over the limit,
/// and none is reported Converged (`walked`): no false accept. With
/// updates of 1,024 bytes: with the default, 15% of the map, more of the
/// peer's far voxels wait, the copy is further from the map the local
/// truth is taken on, and 2 of the estimates missed it by 0.01-0.1
/// degrees (rounds 37-38, measured).
#[test]
fn under_heavy_drift_the_robots_measure_their_walk_and_claim_nothing() {
    let (records, summary) = session(&["--drift", "2%,2", "--seed", "1", "--update-budget", "1024"]);
    records.iter().for_each(check_record_fields);
    let walked: Vec<&Value> = records.iter().filter(|r| r["walked"] == true).collect();
    assert!(walked.len() >= 40, "{summary}");
    let strict = |r: &&&Value| r["e_t"].as_f64().unwrap() < 0.5 && r["e_r"].as_f64().unwrap() < 1.0;
    let local = |r: &&&Value| r["e_t_local"].as_f64().unwrap() < 0.5 && r["e_r_local"].as_f64().unwrap() < 1.0;
    assert!(walked.iter().all(|r| local(&r)), "{summary}");
    assert!(walked.iter().filter(|r| !strict(r)).count() >= 10, "{summary}");
    assert_eq!(summary["wrong_converged"], 0, "{summary}");
    // Each robot's figure, once it has its scans, is over what the
    // benchmark's drift gives (0.06-0.14 degrees).
    let late = records.iter().filter(|r| r["round"].as_u64().unwrap() >= 10);
    assert!(late.clone().all(|r| r["walk"].as_f64().is_some_and(|w| w > 0.15)), "{summary}");
    assert!(late.clone().all(|r| r["walk_peer"].as_f64().is_some_and(|w| w > 0.15)), "{summary}");
}

/// `--mcap-out` writes the session as a recording: each robot's map every
/// round, its odometry and the Converged estimates on /tf, each as a pose
/// with its covariance, and every estimate's status on /diagnostics; the
/// Python `mcap-ros2-support` decoder, where present, reads every message.
#[test]
fn a_session_is_written_as_a_recording_to_view() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("street");
    synth(&s, 20, 5);
    let seq = s.display().to_string();
    let bag = dir.path().join("session.mcap");
    let b = bag.display().to_string();
    let (records, _) =
        session(&["--robot", &format!("{seq}:0:10"), "--robot", &format!("{seq}:4:14"), "--mcap-out", &b]);
    let rounds = records.iter().map(|r| r["round"].as_u64().unwrap()).max().unwrap() + 1;
    let converged_pairs = records.iter().filter(|r| r["robot"] == 0 && r["status"] == "Converged").count();
    assert!(converged_pairs > 0);
    let err = cosem_tests::cosem_err(&[
        "session",
        "--robot",
        &format!("{seq}:0:10"),
        "--robot",
        &format!("{seq}:4:14"),
        "--mcap-out",
        &format!("{seq}/poses.txt"),
    ]);
    assert!(err.contains("--mcap-out"), "{err}");
    let py = "import sys\nfrom mcap.reader import make_reader\nfrom mcap_ros2.decoder import DecoderFactory\n\
              r = make_reader(open(sys.argv[1], 'rb'), decoder_factories=[DecoderFactory()])\n\
              maps, edges, poses, good, diags, ok = 0, 0, 0, 0, 0, 0\n\
              for schema, channel, message, ros in r.iter_decoded_messages():\n\
              \x20   if channel.topic == '/robot_0/map': maps += 1\n\
              \x20   if channel.topic == '/tf': edges += sum(t.child_frame_id == 'robot_1/odom' for t in ros.transforms)\n\
              \x20   if channel.topic == '/robot_0/peers/robot_1/pose':\n\
              \x20       poses += 1\n\
              \x20       c = ros.pose.covariance\n\
              \x20       good += ros.header.frame_id == 'robot_0/odom' and all(c[7 * k] > 0 for k in range(6))\n\
              \x20   if channel.topic == '/diagnostics':\n\
              \x20       diags += len(ros.status) == 2\n\
              \x20       ok += sum(s.message == 'Converged' and s.level == 0 and s.hardware_id == 'robot_0' for s in ros.status)\n\
              print(maps, edges, poses, good, diags, ok)\n";
    if let Some(text) = cosem_tests::python_or_skip(py, &[&b]) {
        let c = converged_pairs;
        assert_eq!(text.trim(), format!("{rounds} {c} {c} {c} {rounds} {c}"), "{text}");
    }
}

/// `cosem label` on a town robot's segmentation keeps the robot in the
/// town's world (`world.txt` copied), so a session on camera labels still
/// has its truth.
#[test]
fn labelled_town_robots_stay_in_their_world() {
    let dir = tempfile::tempdir().unwrap();
    let town = dir.path().join("town");
    let t = town.display().to_string();
    cosem_ok(&["synth", "--town", "--out", &t, "--frames", "6", "--seed", "2"]);
    let (data, out) = (town.join("robot_1"), dir.path().join("labelled"));
    let (d, o) = (data.display().to_string(), out.display().to_string());
    cosem_ok(&["label", "--data", &d, "--seg", &format!("{d}/seg_2"), "--out", &o, "--frames", "0:6"]);
    let world = |p: &std::path::Path| std::fs::read_to_string(p.join("world.txt")).unwrap();
    assert_eq!(world(&out), world(&data));
    assert_eq!(std::fs::read(out.join("poses.txt")).unwrap(), std::fs::read(data.join("poses.txt")).unwrap());
}

/// A robot adopts only a fix its peer made in its latest round, not one
/// the peer held the round before, wherever tracking moved it
/// (`cosem_core::session::made_this_round`). Camera labels, town seed 6,
/// drift `1%,1`, frames 0-20 (the robots far apart, no true overlap): the
/// labels' errors give robot 0's search a street turned by about 100
/// degrees (held, unconfirmed); tracked the next round it slid 9 degrees
/// and 5 m, and robot 1, whose own search found nothing, adopted it as new
/// (agreement 0.51 against the margin's 0.50): both reported it
/// `Converged`, 77-81 m off. Now nothing the robots say is `Converged`.
#[test]
fn a_look_alike_that_slid_in_tracking_is_not_adopted() {
    let dir = tempfile::tempdir().unwrap();
    let town = dir.path().join("town");
    let t = town.display().to_string();
    cosem_ok(&["synth", "--town", "--out", &t, "--frames", "20", "--seed", "6"]);
    let mut robots = vec![];
    for i in 0..2 {
        let data = town.join(format!("robot_{i}")).display().to_string();
        let out = town.join(format!("labelled_{i}")).display().to_string();
        cosem_ok(&["label", "--data", &data, "--seg", &format!("{data}/seg_2"), "--out", &out, "--frames", "0:20"]);
        robots.push(format!("{out}:0:20"));
    }
    let args = ["--robot", &robots[0], "--robot", &robots[1], "--drift", "1%,1", "--seed", "6"];
    let (records, summary) = session(&args);
    assert_eq!(records.len(), 20);
    // The case arises: a look-alike passes a robot's verdict and is held.
    let held_wrong = |r: &&Value| r["fix"] == "held" && r["e_t"].as_f64().is_some_and(|e| e > 10.0);
    assert!(records.iter().any(|r| held_wrong(&r)), "no look-alike held: the case no longer arises");
    assert!(records.iter().all(|r| r["overlap_true"].as_f64().unwrap() < 0.05), "the robots are apart");
    assert!(records.iter().all(|r| r["adopted"] == false), "a held fix adopted");
    assert!(records.iter().all(|r| r["status"] != "Converged"), "a look-alike reported Converged");
    assert_eq!(summary["wrong_converged"], 0);
}

/// Two session robots on emulated mps2-an386 boards (`--on-board`), over
/// the town's first meeting (frames 44 to 104 of seed 1, drifted), their
/// UARTs joined by a line that damages 2% of bytes (substituted, dropped,
/// duplicated): 30 rounds each, every round equal to the host's twin of
/// the same robots (on a clean simulated line: the line changes the bytes,
/// never the maps), within 3e8 instructions a round, fixes in the meeting
/// and none wrong.
#[test]
fn two_session_robots_run_on_boards_equal_to_their_twin() {
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let town = dir.path().join("town");
    let t = town.display().to_string();
    cosem_ok(&["synth", "--town", "--out", &t, "--frames", "104", "--seg", "none", "--seed", "1"]);
    let (a, b) = (format!("{t}/robot_0:44:104"), format!("{t}/robot_1:44:104"));
    let args =
        ["session", "--on-board", "--json", "--robot", &a, "--robot", &b, "--drift", "1%,0.5", "--line", "lossy=0.02"];
    let out = cosem_ok(&args);
    let mut lines: Vec<Value> = out.lines().map(|l| serde_json::from_str(l).expect("a JSON line")).collect();
    let summary = lines.pop().expect("a summary line")["summary"].clone();
    eprintln!("{summary}");
    assert_eq!(summary["equal_to_twin"], true, "{summary}");
    assert_eq!(summary["rounds"], 30, "{summary}");
    for (i, board) in summary["boards"].as_array().unwrap().iter().enumerate() {
        assert_eq!(board["rounds"], 30, "board {i}: {board}");
        assert!(board["failed"].is_null(), "board {i}: {board}");
        assert_eq!(board["twin_max_dt"].as_f64(), Some(0.0), "board {i}: bit for bit: {board}");
        assert!(board["most_round_instructions"].as_u64().unwrap() <= 300_000_000, "board {i}: {board}");
        assert!(board["converged"].as_u64().unwrap() >= 10, "board {i}: {board}");
        assert_eq!(board["wrong_converged"], 0, "board {i}: {board}");
    }
    assert_eq!(lines.len(), 2 * 30);
    for l in &lines {
        for key in ["round", "robot", "peer", "status", "kind", "T_own_peer", "update_bytes", "line_bytes"] {
            assert!(!l[key].is_null(), "{key} missing: {l}");
        }
        // Each board measures its heading walk from its scans and hears its
        // peer's with the peer's update: at this drift under the limit.
        assert_eq!(l["walked"], false, "{l}");
        if l["round"].as_u64().unwrap() >= 6 {
            let calm = |k: &str| l[k].as_f64().is_some_and(|w| (0.0..0.2).contains(&w));
            assert!(calm("walk") && calm("walk_peer"), "{l}");
        }
    }
}

/// Two session boards over a longer stretch of the town (seed 1, network
/// labels, frames 0 to 118: the robots apart, their first meeting and
/// their parting; 59 rounds, a clean line): every round equal to the
/// twin, none wrong, and every round within 3e8 instructions, the rounds
/// after the parting too, where each robot searches for its peer from no
/// prior on maps that share little and EM slides on every placement it
/// tries. Before a board's EM remembered the blocks of its sampled
/// entries (`SESSION_REACH`), 6 of those robot-rounds took 3.0e8 to 3.34e8;
/// since a round's estimate is on a work budget, 11 robot-rounds after the
/// parting are cut short (a placement not refined), and none is over.
#[test]
fn a_longer_session_on_boards_keeps_every_round_within_the_instruction_budget() {
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let town = dir.path().join("town");
    let t = town.display().to_string();
    cosem_ok(&["synth", "--town", "--out", &t, "--frames", "118", "--seg", "none", "--seed", "1"]);
    let (a, b) = (format!("{t}/robot_0:0:118"), format!("{t}/robot_1:0:118"));
    let noise = ["--label-noise", "network", "--seed", "1", "--drift", "1%,0.5"];
    let out = cosem_ok(&[&["session", "--on-board", "--json", "--robot", &a, "--robot", &b][..], &noise[..]].concat());
    let mut lines: Vec<Value> = out.lines().map(|l| serde_json::from_str(l).expect("a JSON line")).collect();
    let summary = lines.pop().expect("a summary line")["summary"].clone();
    eprintln!("{summary}");
    assert_eq!(summary["equal_to_twin"], true, "{summary}");
    for (i, board) in summary["boards"].as_array().unwrap().iter().enumerate() {
        assert_eq!(board["rounds"], 59, "board {i}: {board}");
        assert!(board["failed"].is_null(), "board {i}: {board}");
        assert!(board["most_round_instructions"].as_u64().unwrap() <= 300_000_000, "board {i}: {board}");
        assert!(board["converged"].as_u64().unwrap() >= 10, "board {i}: {board}");
        assert_eq!(board["wrong_converged"], 0, "board {i}: {board}");
    }
    let prior_free = lines.iter().filter(|l| l["kind"] == "prior-free" && l["round"].as_u64() > Some(52)).count();
    assert!(prior_free > 0, "no prior-free round after the parting: the test no longer covers them");
    // The round's work budget (`SESSION_WORK`, 2.0e8 at the fitted costs)
    // bounds each estimate, and cuts some after the parting; the fitted
    // costs still bound what the board counted (to the 1.2e7 the fit
    // missed by at most, over 780 robot-rounds of three whole sessions).
    let n = |l: &Value, k: &str| l[k].as_u64().unwrap_or_else(|| panic!("{k} missing: {l}"));
    for l in &lines {
        assert!(n(l, "work") <= 200_000_000, "{l}");
        assert!(l["instructions"][3].as_u64().unwrap() <= n(l, "work") + 15_000_000, "the costs no longer bound: {l}");
    }
    let cut = lines.iter().filter(|l| l["work_cut"] == true).count();
    assert!(cut > 0, "no round was cut: the test no longer covers the budget");
}
