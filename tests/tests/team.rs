//! `cosem team` end to end: robots cut from one drive placed in robot 0's
//! frame with no prior, a robot from elsewhere unplaced, an injected false
//! match left out by the cycle check. Tolerances from the issue: 0.2 m and
//! 0.5 degrees.

use cosem_tests::{cosem, real_data, synth};
use serde_json::Value;

fn team(args: &[&str]) -> (Value, Option<i32>) {
    let mut all = vec!["team", "--json"];
    all.extend_from_slice(args);
    let out = cosem(&all);
    let text = String::from_utf8_lossy(&out.stdout);
    let v: Value = serde_json::from_str(&text).unwrap_or_else(|e| {
        panic!("{e}: {text} {}", String::from_utf8_lossy(&out.stderr));
    });
    (v, out.status.code())
}

fn assert_placed(v: &Value, index: usize) {
    let r = &v["robots"][index];
    assert_eq!(r["placed"], true, "robot {index}: {r}");
    assert_eq!(r["transform"].as_array().map(Vec::len), Some(16), "{r}");
    assert_eq!(r["covariance"].as_array().map(Vec::len), Some(36), "{r}");
    let (et, er) = (r["e_t"].as_f64().unwrap(), r["e_r"].as_f64().unwrap());
    assert!(et < 0.2 && er < 0.5, "robot {index}: e_t {et} m, e_r {er} deg");
    assert!(r["bytes_sent"].as_u64().unwrap() > 0 && r["bytes_received"].as_u64().unwrap() > 0, "{r}");
}

fn accepted(v: &Value, a: u64, b: u64) -> bool {
    let m = v["matches"].as_array().unwrap().iter().find(|m| m["a"] == a && m["b"] == b).unwrap();
    m["accepted"].as_bool().unwrap()
}

#[test]
fn a_drive_cut_in_three_is_placed_and_a_robot_from_elsewhere_is_not() {
    let (Some(k00), Some(k07)) = (real_data("kitti00"), real_data("kitti07")) else { return };
    let (a, b) = (k00.display().to_string(), k07.display().to_string());
    let robots = [format!("{a}:0:3"), format!("{a}:3:6"), format!("{a}:6:10"), format!("{b}:0:3")];
    for inject in [None, Some("0,1")] {
        let mut args: Vec<&str> = robots.iter().flat_map(|r| ["--robot", r.as_str()]).collect();
        if let Some(i) = inject {
            args.extend_from_slice(&["--inject-false-match", i]);
        }
        let (v, code) = team(&args);
        for i in 0..3 {
            assert_placed(&v, i);
        }
        let r3 = &v["robots"][3];
        assert_eq!(r3["placed"], false, "{r3}");
        assert!(r3.get("transform").is_none(), "{r3}");
        assert_eq!(code, Some(5), "a robot unplaced");
        assert_eq!(accepted(&v, 0, 1), inject.is_none(), "the injected match must be left out");
        assert!(accepted(&v, 1, 0));
    }
}

#[test]
fn a_synthetic_team_of_four_is_placed_despite_a_false_match() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 12, 21);
    let s = seq.display().to_string();
    let robots: Vec<String> = (0..4).map(|i| format!("{s}:{}:{}", 3 * i, 3 * i + 3)).collect();
    let args: Vec<&str> = robots.iter().flat_map(|r| ["--robot", r.as_str()]).collect();
    // One direction, then one false match seen from both robots (on the
    // cycles 0-1-2, 1-2-3 and more).
    for inject in [&["1,2"][..], &["1,2", "2,1"][..]] {
        let mut args = args.clone();
        for i in inject {
            args.extend_from_slice(&["--inject-false-match", i]);
        }
        let (v, code) = team(&args);
        for i in 0..4 {
            assert_placed(&v, i);
        }
        assert_eq!(code, Some(0));
        assert!(!accepted(&v, 1, 2));
        assert_eq!(accepted(&v, 2, 1), inject.len() == 1);
        assert_eq!(v["matches"].as_array().unwrap().len(), 12);
        // Every pair of four robots lies on a cycle: every placement checked.
        assert!((0..4).all(|i| v["robots"][i]["verified"] == true), "{}", v["robots"]);
    }
}

/// Two robots: no cycle can check a match, so a false match seen from both
/// robots places robot 1 wrongly, and the output says it is unverified.
#[test]
fn a_two_robot_team_says_its_placement_is_unverified() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 6, 22);
    let s = seq.display().to_string();
    let (a, b) = (format!("{s}:0:3"), format!("{s}:3:6"));
    let (v, code) = team(&["--robot", &a, "--robot", &b, "--inject-false-match", "0,1", "--inject-false-match", "1,0"]);
    assert_eq!(code, Some(0));
    assert_eq!(v["schema_version"], 2);
    let r1 = &v["robots"][1];
    assert_eq!((r1["placed"].as_bool(), r1["verified"].as_bool()), (Some(true), Some(false)), "{r1}");
    assert!(r1["e_t"].as_f64().unwrap() > 1.0, "the injected match is 5 m off: {r1}");
    let out = cosem_tests::cosem_ok(&["team", "--robot", &a, "--robot", &b]);
    assert!(out.contains("verified by no cycle"), "{out}");
}

#[test]
fn a_pair_met_elsewhere_is_a_group_of_its_own() {
    let (Some(k00), Some(k08)) = (real_data("kitti00"), real_data("kitti08-loop")) else { return };
    let (a, b) = (k00.display().to_string(), k08.display().to_string());
    let robots = [format!("{a}:0:3"), format!("{a}:3:6"), format!("{b}:720:721"), format!("{b}:1500:1501")];
    let args: Vec<&str> = robots.iter().flat_map(|r| ["--robot", r.as_str()]).collect();
    let (v, code) = team(&args);
    assert_placed(&v, 1);
    assert_eq!(code, Some(5));
    // kitti08's two passes (opposite directions) find each other, in robot 2's frame.
    for i in [2, 3] {
        let r = &v["robots"][i];
        assert_eq!((r["placed"].as_bool(), r["group"].as_u64()), (Some(false), Some(2)), "{r}");
        assert_eq!(r["group_transform"].as_array().map(Vec::len), Some(16), "{r}");
    }
    let r3 = &v["robots"][3];
    let (et, er) = (r3["e_t"].as_f64().unwrap(), r3["e_r"].as_f64().unwrap());
    assert!(et < 0.2 && er < 0.5, "robot 3 in robot 2's frame: e_t {et} m, e_r {er} deg");
}

/// One team of emulated boards at a time (each QEMU busy-waits on its UARTs).
static BOARDS: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Checks an on-board run: every board finished, each agrees with the
/// host's run of the same robots on the same fed points (1e-4 m) and with
/// board 0, and measured its peak stack.
fn assert_boards_agree(v: &Value, boards: usize) {
    assert_eq!(v["on_board"], true, "{v}");
    let b = v["boards"].as_array().unwrap();
    assert_eq!(b.len(), boards, "{v}");
    for board in b {
        assert_eq!(board["finished"], true, "{board}");
        assert_eq!(board["exit_code"], 0, "{board}");
        assert_eq!(board["heard"].as_array().unwrap().len(), boards, "every board holds every estimate: {board}");
        assert!(board["difference_to_host_m"].as_f64().unwrap() <= 1e-4, "{board}");
        assert!(board["difference_to_board0_m"].as_f64().unwrap() <= 1e-4, "{board}");
        assert_eq!(board["same_groups_as_host"], true, "{board}");
        assert!(board["peak_stack_bytes"].as_u64().unwrap() > 0, "{board}");
        assert!(board["map_voxels"].as_u64().unwrap() > 1000, "{board}");
    }
    assert!(v["host_difference_m"].as_f64().unwrap() <= 1e-4, "{v}");
}

#[test]
fn a_drive_cut_in_three_is_placed_on_boards_and_a_robot_from_elsewhere_is_not() {
    let (Some(k00), Some(k07)) = (real_data("kitti00"), real_data("kitti07")) else { return };
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let (a, b) = (k00.display().to_string(), k07.display().to_string());
    let robots = [format!("{a}:0:3"), format!("{a}:3:6"), format!("{a}:6:10"), format!("{b}:0:3")];
    let mut args: Vec<&str> = robots.iter().flat_map(|r| ["--robot", r.as_str()]).collect();
    args.push("--on-board");
    let (v, code) = {
        let _one = BOARDS.lock().unwrap_or_else(|e| e.into_inner());
        team(&args)
    };
    assert_boards_agree(&v, 4);
    for i in 0..3 {
        assert_placed(&v, i);
    }
    // Bytes that came in while a board prepared and matched (the next
    // round's exchange, estimates, resends) are taken by the receive
    // interrupts into the rings; how many depends on how the host schedules
    // the emulators, so it is printed, not asserted (a timed figure). That
    // every exchange still delivered its map whole is asserted above: the
    // placements are the host's to the bit.
    let during: Vec<u64> =
        v["boards"].as_array().unwrap().iter().map(|b| b["link_bytes_while_matching"].as_u64().unwrap()).collect();
    eprintln!("bytes that came in while matching, per board: {during:?}");
    let r3 = &v["robots"][3];
    assert_eq!(r3["placed"], false, "{r3}");
    assert_eq!(code, Some(5), "a robot unplaced");
    for m in v["matches"].as_array().unwrap() {
        let with_3 = m["a"] == 3 || m["b"] == 3;
        assert_eq!(m["accepted"].as_bool(), Some(!with_3), "{m}");
    }
}

#[test]
fn a_drive_cut_in_three_is_placed_on_stm32f405_boards_and_a_robot_from_elsewhere_is_not() {
    let (Some(k00), Some(k07)) = (real_data("kitti00"), real_data("kitti07")) else { return };
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let (a, b) = (k00.display().to_string(), k07.display().to_string());
    let on = ["--on-board", "--board", "stm32f405"];
    let robots = [format!("{a}:0:3"), format!("{a}:3:6"), format!("{a}:6:10")];
    let mut args: Vec<&str> = robots.iter().flat_map(|r| ["--robot", r.as_str()]).collect();
    args.extend_from_slice(&on);
    let (v, code) = {
        let _one = BOARDS.lock().unwrap_or_else(|e| e.into_inner());
        team(&args)
    };
    assert_boards_agree(&v, 3);
    for i in 0..3 {
        assert_placed(&v, i);
    }
    assert_eq!(code, Some(0));
    // The team robot within the chip's 192 KiB: its statics leave this
    // stack (the link checks it), and its map holds 1,760 voxels.
    for board in v["boards"].as_array().unwrap() {
        assert!(board["peak_stack_bytes"].as_u64().unwrap() <= 47_104, "{board}");
        assert!(board["map_voxels"].as_u64().unwrap() <= 1760, "{board}");
    }
    let robots = [format!("{a}:0:3"), format!("{a}:3:6"), format!("{b}:0:3")];
    let mut args: Vec<&str> = robots.iter().flat_map(|r| ["--robot", r.as_str()]).collect();
    args.extend_from_slice(&on);
    let (v, code) = {
        let _one = BOARDS.lock().unwrap_or_else(|e| e.into_inner());
        team(&args)
    };
    assert_boards_agree(&v, 3);
    assert_placed(&v, 1);
    assert_eq!(v["robots"][2]["placed"], false, "{v}");
    assert_eq!(code, Some(5), "a robot unplaced");
}

#[test]
fn a_synthetic_street_cut_in_three_is_placed_on_boards() {
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 9, 5);
    let s = seq.display().to_string();
    let robots: Vec<String> = (0..3).map(|i| format!("{s}:{}:{}", 3 * i, 3 * i + 3)).collect();
    let mut args: Vec<&str> = robots.iter().flat_map(|r| ["--robot", r.as_str()]).collect();
    args.push("--on-board");
    let (v, code) = {
        let _one = BOARDS.lock().unwrap_or_else(|e| e.into_inner());
        team(&args)
    };
    assert_boards_agree(&v, 3);
    for i in 0..3 {
        assert_placed(&v, i);
    }
    assert_eq!(code, Some(0));
}

#[test]
fn a_synthetic_street_cut_in_eight_is_placed_despite_a_false_match_both_ways() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth(&seq, 24, 21);
    let s = seq.display().to_string();
    let robots: Vec<String> = (0..8).map(|i| format!("{s}:{}:{}", 3 * i, 3 * i + 3)).collect();
    let mut args: Vec<&str> = robots.iter().flat_map(|r| ["--robot", r.as_str()]).collect();
    args.extend_from_slice(&["--inject-false-match", "3,4", "--inject-false-match", "4,3"]);
    let (v, code) = team(&args);
    for i in 0..8 {
        assert_placed(&v, i);
    }
    assert_eq!(code, Some(0));
    assert!(!accepted(&v, 3, 4) && !accepted(&v, 4, 3));
    assert_eq!(v["matches"].as_array().unwrap().len(), 56);
    // Each robot sent its map over its 7 links, once each.
    for r in v["robots"].as_array().unwrap() {
        let (sent, voxels) = (r["bytes_sent"].as_u64().unwrap(), r["voxels"].as_u64().unwrap());
        assert!(sent > 7 * voxels && sent < 7 * 8 * voxels, "{r}");
    }
}
