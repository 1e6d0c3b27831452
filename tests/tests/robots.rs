//! Two robots on emulated Cortex-M4F boards (`cosem robots`): each builds
//! its map on board from the fed scans, the maps cross the UART0 line, each
//! robot matches on board and must agree with the ground truth and, to
//! rounding, with the host's run of the same pipeline. A silent or
//! corrupting line must end in a typed link error, not a hang. Skipped where
//! QEMU or the ARM target is missing (`tests/run` installs both).

use serde_json::Value;

/// One pair of emulated robots at a time: each QEMU busy-waits on its
/// UARTs, and several pairs on a 2-core machine starve the emulators' I/O.
static ONE_PAIR: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Runs `cosem robots` with `args`; returns its JSON and whether it succeeded.
fn robots(args: &[&str]) -> (Value, bool) {
    let _one = ONE_PAIR.lock().unwrap_or_else(|e| e.into_inner());
    let mut all = vec!["robots", "--json"];
    all.extend_from_slice(args);
    let out = cosem_tests::cosem(&all);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    let json: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("cosem robots {args:?}: {e}\n{stderr}\n{}", String::from_utf8_lossy(&out.stdout)));
    (json, out.status.success())
}

fn matrix(v: &Value) -> cosem_core::geometry::Isometry3<f64> {
    let n: Vec<f64> = v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    cosem_core::geometry::rigid_from_matrix(&nalgebra::Matrix4::from_row_slice(&n)).expect("a rigid transform")
}

/// The whole onboard pipeline of a robot that converged (mapping,
/// preparation, prior-free landmark search, match) within 3e8 instructions
/// (QEMU's virtual nanoseconds under `-icount shift=0`), printed on every
/// run: a count, not a time, so the same on every machine.
fn check_budget(i: usize, r: &Value) {
    check_budget_of(i, r, 300_000_000);
}

/// [`check_budget`] against `budget` instructions.
fn check_budget_of(i: usize, r: &Value, budget: u64) {
    let n = |k: &str| r[k].as_u64().unwrap_or_else(|| panic!("robot {i}: no {k}: {r}"));
    let (map, prepare, locate, matching) =
        (n("map_instructions"), n("prepare_instructions"), n("locate_instructions"), n("match_instructions"));
    let total = map + prepare + locate + matching;
    eprintln!(
        "robot {i} pipeline: map {map} + prepare {prepare} + locate {locate} + match {matching} = {total} instructions"
    );
    assert!(total <= budget, "robot {i}: pipeline of {total} instructions over {budget}: {r}");
}

/// Checks both robots converged near the truth and equal the host's runs,
/// each within 3e8 instructions.
fn check_pair(json: &Value) {
    check_pair_within(json, 300_000_000, 1.0);
}

/// [`check_pair`] with each robot's pipeline within `budget` instructions,
/// on a line that may duplicate bytes: each robot received at most `dups`
/// times the bytes its peer sent.
fn check_pair_within(json: &Value, budget: u64, dups: f64) {
    let gt = matrix(&json["ground_truth"]);
    let truths = [gt, gt.inverse()];
    let hosts = [matrix(&json["host"]["transform"]), matrix(&json["host_b"]["transform"])];
    for (i, r) in json["robots"].as_array().unwrap().iter().enumerate() {
        assert_eq!(r["id"], i);
        assert_eq!(r["status"], "Converged", "robot {i}: {r}");
        assert_eq!(r["exit_code"], 0, "robot {i}: {r}");
        let t = matrix(&r["transform"]);
        let (e_t, e_r) = cosem_core::geometry::pose_errors(&t, &truths[i]);
        assert!(e_t < 0.2 && e_r < 0.5, "robot {i} off the truth: {e_t} m, {e_r} deg");
        let (d_t, d_r) = cosem_core::geometry::pose_errors(&t, &hosts[i]);
        assert!(d_t < 1e-4 && d_r < 1e-3, "robot {i} differs from the host: {d_t} m, {d_r} deg");
        for key in ["instructions", "map_voxels", "bytes_sent", "bytes_received"] {
            assert!(r[key].as_u64().unwrap() > 0, "robot {i}: {key}");
        }
        eprintln!(
            "robot {i}: e_t {e_t:.3} m e_r {e_r:.3} deg; {} voxels; {} B out; match {} instructions",
            r["map_voxels"], r["bytes_sent"], r["instructions"]
        );
        check_budget_of(i, r, budget);
        // The mps2-an386 robot in 512 KiB with its stack (its link also
        // checks the statics leave 36 KiB of stack in 512 KiB).
        if r["board"] == "mps2-an386" {
            let ram = r["static_ram_bytes"].as_u64().unwrap() + r["peak_stack_bytes"].as_u64().unwrap();
            assert!(ram <= 512 * 1024, "robot {i} takes {ram} bytes of RAM with its stack");
        }
    }
    // Each robot received the other's whole map, and no byte the other did
    // not send (the last acknowledgements may still be on the line when a
    // robot that heard its peer is finished stops listening).
    let r = json["robots"].as_array().unwrap();
    for (a, b) in [(0, 1), (1, 0)] {
        assert_eq!(r[a]["received_voxels"], r[b]["map_voxels"]);
        let (got, sent) = (r[a]["bytes_received"].as_u64().unwrap(), r[b]["bytes_sent"].as_u64().unwrap());
        assert!(got as f64 <= sent as f64 * dups, "{}", r[a]);
    }
}

#[test]
fn two_robots_match_kitti00_on_board() {
    let Some(data) = cosem_tests::real_data("kitti00") else { return };
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let (json, ok) = robots(&["--data", &data.display().to_string(), "--a", "0:5", "--b", "5:10"]);
    assert!(ok, "{json}");
    check_pair(&json);
}

fn synthetic(frames: usize) -> tempfile::TempDir {
    let tmp = tempfile::tempdir().unwrap();
    cosem_tests::synth(&tmp.path().join("seq"), frames, 5);
    tmp
}

#[test]
fn two_robots_match_a_synthetic_street_on_board() {
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let tmp = synthetic(10);
    let seq = tmp.path().join("seq").display().to_string();
    let (json, ok) = robots(&["--data", &seq, "--a", "0:5", "--b", "5:10"]);
    assert!(ok, "{json}");
    check_pair(&json);
}

/// Checks both robots searched every heading and offset on board (no prior given).
fn check_no_prior(json: &Value) {
    assert!(json["prior"].is_null(), "{json}");
    for r in json["robots"].as_array().unwrap() {
        let g = &r["global"];
        assert!(g["score"].as_u64().unwrap() > 0 && g["evaluations"].as_u64().unwrap() > 0, "{r}");
        assert!(r["locate_instructions"].as_u64().unwrap() > 0, "{r}");
    }
}

#[test]
fn two_robots_that_share_nothing_say_so_within_the_budget_on_board() {
    // kitti00-loop frames 88 and 850, 308 m apart, no prior: both robots
    // say NoOverlap, each within the same 3e8 instructions as a pair that
    // matches (the search stops at the robot's node budget and the best
    // placement found is refined once).
    let Some(data) = cosem_tests::real_data("kitti00-loop") else { return };
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let data = data.display().to_string();
    let (json, ok) = robots(&["--data", &data, "--a", "88:89", "--b", "850:851", "--no-prior"]);
    assert!(!ok, "{json}");
    for (i, r) in json["robots"].as_array().unwrap().iter().enumerate() {
        assert_eq!(r["status"], "NoOverlap", "robot {i}: {r}");
        check_budget(i, r);
        let g = &r["global"];
        let nodes = g["evaluations"].as_u64().unwrap();
        assert!(nodes <= u64::from(cosem_core::robot::SEARCH_NODES) + 8, "robot {i}: {nodes} nodes");
        assert_eq!(g["refined"], 1, "robot {i}: {r}");
    }
    check_no_prior(&json);
}

#[test]
fn two_robots_align_the_opposite_direction_loop_with_no_prior_on_board() {
    // kitti08-loop: the same place driven in opposite directions (yaw about -148 degrees).
    let Some(data) = cosem_tests::real_data("kitti08-loop") else { return };
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let data = data.display().to_string();
    let (json, ok) = robots(&["--data", &data, "--a", "720:721", "--b", "1500:1501", "--no-prior"]);
    assert!(ok, "{json}");
    check_pair(&json);
    check_no_prior(&json);
}

#[test]
fn two_robots_find_each_other_with_a_networks_labels_and_no_prior_on_board() {
    // Labels with a segmentation network's errors (`--label-noise
    // network`), no prior: both converge near the truth, within the same
    // 3e8 instructions as with ground-truth labels (the prior-free search's
    // bounds are looser with noisy labels, twice the nodes: 2.2-2.7e8 here).
    let Some(data) = cosem_tests::real_data("kitti00") else { return };
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let data = data.display().to_string();
    let args = ["--data", &data, "--a", "0:5", "--b", "5:10", "--no-prior", "--label-noise", "network"];
    let (json, ok) = robots(&args);
    assert!(ok, "{json}");
    assert!(json["label_noise"].as_str().is_some_and(|s| s.contains("Network")), "{json}");
    check_pair(&json);
    check_no_prior(&json);
}

#[test]
fn two_robots_match_a_synthetic_street_with_no_prior_on_board() {
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let tmp = synthetic(10);
    let seq = tmp.path().join("seq").display().to_string();
    let (json, ok) = robots(&["--data", &seq, "--a", "0:5", "--b", "5:10", "--no-prior"]);
    assert!(ok, "{json}");
    check_pair(&json);
    check_no_prior(&json);
}

/// A line that substitutes, drops and duplicates 10% of its bytes (the
/// link sends blocks there): the maps cross whole, and each robot's result
/// is the host's to the last digit (`check_pair`): two mps2-an386 robots on
/// the synthetic street, two STM32F405s within their 192 KiB on kitti00.
#[test]
fn two_robots_match_across_a_line_that_drops_and_duplicates_bytes() {
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let tmp = synthetic(10);
    let seq = tmp.path().join("seq").display().to_string();
    let kitti = cosem_tests::real_data("kitti00").map(|d| d.display().to_string());
    let mut runs = vec![(seq.as_str(), "mps2-an386")];
    runs.extend(kitti.as_deref().map(|k| (k, "stm32f405")));
    for (data, board) in runs {
        let args = [
            "--data",
            data,
            "--a",
            "0:5",
            "--b",
            "5:10",
            "--line",
            "lossy=0.1",
            "--board-a",
            board,
            "--board-b",
            board,
        ];
        let (json, ok) = robots(&args);
        assert!(ok, "{board}: {json}");
        // A duplicate in 30 bytes: the bytes received may exceed those sent.
        check_pair_within(&json, 300_000_000, 1.1);
        if board == "stm32f405" {
            check_stm32f405_pair(&json);
        }
        let sent = json["robots"][0]["bytes_sent"].as_u64().unwrap();
        eprintln!("{board}: robot 0 sent {sent} bytes over a 10% line");
    }
}

#[test]
fn a_silent_or_corrupting_line_is_a_typed_link_error() {
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let tmp = synthetic(4);
    let seq = tmp.path().join("seq").display().to_string();
    // A line that flips a bit in 70% of bytes: frames never pass, even the
    // deframer's one-error repair. (At 30%, repaired short frames do pass:
    // such a line crawls, it is not silent.)
    for line in ["silent", "corrupt=0.7"] {
        let (json, ok) =
            robots(&["--data", &seq, "--a", "0:2", "--b", "2:4", "--line", line, "--silence", "3", "--timeout", "300"]);
        assert!(!ok, "{line}: {json}");
        for r in json["robots"].as_array().unwrap() {
            assert_eq!(r["error"]["stage"], "link", "{line}: {r}");
            let message = r["error"]["message"].as_str().unwrap();
            assert!(message == "peer silent" || message.starts_with("gave up"), "{line}: {message}");
            // It exited on its own, non-zero (not killed at the deadline).
            assert_eq!(r["exit_code"], 1, "{line}: {r}");
        }
    }
}

/// A mixed pair that both match: robot A on mps2-an386 (a 0.5 m map of
/// 7,000+ voxels), robot B on an STM32F405 (which holds about 3,000 of a
/// peer's). B's `Hello` says what it holds, so A sends the part of its map
/// nearest its anchor that fits, instead of a map B must refuse; both
/// robots equal their host twins, and B, matching A's part, is placed.
#[test]
fn a_mixed_pair_runs_the_larger_robot_sending_what_fits_the_smaller() {
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let Some(data) = cosem_tests::real_data("kitti00") else { return };
    let data = data.display().to_string();
    let (json, _) = robots(&["--data", &data, "--a", "0:5", "--b", "5:10", "--board-b", "stm32f405", "--voxel", "0.5"]);
    let r = json["robots"].as_array().unwrap();
    let n = |i: usize, k: &str| r[i][k].as_u64().unwrap_or_else(|| panic!("robot {i}: no {k}: {}", r[i]));
    assert!(r.iter().all(|x| x.get("error").is_none()), "no robot failed: {json}");
    assert!(n(0, "map_voxels") > n(1, "received_voxels"), "A's map does not fit B: {json}");
    assert!(n(1, "received_voxels") >= 2_000, "B holds a part of A's map: {json}");
    assert_eq!(n(0, "received_voxels"), n(1, "map_voxels"), "B's map fits A whole");
    let hosts = [&json["host"], &json["host_b"]];
    for (i, robot) in r.iter().enumerate() {
        assert_eq!(robot["status"], hosts[i]["status"], "robot {i} as its host twin: {json}");
        let (d_t, d_r) =
            cosem_core::geometry::pose_errors(&matrix(&robot["transform"]), &matrix(&hosts[i]["transform"]));
        assert!(d_t < 1e-4 && d_r < 1e-3, "robot {i} differs from the host: {d_t} m, {d_r} deg");
    }
    assert_eq!(r[1]["status"], "Converged", "{}", r[1]);
    let gt = matrix(&json["ground_truth"]).inverse();
    let (e_t, e_r) = cosem_core::geometry::pose_errors(&matrix(&r[1]["transform"]), &gt);
    assert!(e_t < 0.2 && e_r < 0.5, "robot B off the truth: {e_t} m, {e_r} deg");
    let ram = n(1, "static_ram_bytes") + n(1, "peak_stack_bytes");
    assert!(ram <= 192 * 1024, "robot B takes {ram} bytes of RAM with its stack");
    check_budget(1, &r[1]);
}

/// Checks a heterogeneous pair: robot A on mps2-an386 received B's map and
/// matched; robot B on an STM32F405 sent its map, took none, and reports
/// A's result inverted; both near the truth and equal to the host's runs;
/// robot B within the STM32F405's 192 KiB.
fn check_one_sided(json: &Value) {
    assert_eq!(json["schema_version"], 3, "{json}");
    let gt = matrix(&json["ground_truth"]);
    let truths = [gt, gt.inverse()];
    let hosts = [matrix(&json["host"]["transform"]), matrix(&json["host_b"]["transform"])];
    let r = json["robots"].as_array().unwrap();
    for (i, robot) in r.iter().enumerate() {
        assert_eq!(robot["status"], "Converged", "robot {i}: {robot}");
        assert_eq!(robot["exit_code"], 0, "robot {i}: {robot}");
        let t = matrix(&robot["transform"]);
        let (e_t, e_r) = cosem_core::geometry::pose_errors(&t, &truths[i]);
        assert!(e_t < 0.2 && e_r < 0.5, "robot {i} off the truth: {e_t} m, {e_r} deg");
        let (d_t, d_r) = cosem_core::geometry::pose_errors(&t, &hosts[i]);
        assert!(d_t < 1e-4 && d_r < 1e-3, "robot {i} differs from the host: {d_t} m, {d_r} deg");
        assert!(robot["static_ram_bytes"].as_u64().unwrap() > 0 && robot["peak_stack_bytes"].as_u64().unwrap() > 0);
        check_budget(i, robot);
    }
    assert_eq!((r[0]["board"].as_str(), r[1]["board"].as_str()), (Some("mps2-an386"), Some("stm32f405-sender")));
    assert_eq!(r[0]["received_voxels"], r[1]["map_voxels"]);
    assert_eq!(r[1]["received_voxels"], 0, "robot B takes no map");
    assert_eq!(r[1]["match_instructions"], 0, "robot B does not match");
    let b_ram = r[1]["static_ram_bytes"].as_u64().unwrap() + r[1]["peak_stack_bytes"].as_u64().unwrap();
    assert!(b_ram <= 192 * 1024, "robot B takes {b_ram} bytes");
    // A full map (4,681 voxels in 128 KiB) evicts its farthest eighth and
    // keeps at least 4,096.
    assert!(r[1]["map_voxels"].as_u64().unwrap() >= 4096, "{}", r[1]);
}

#[test]
fn robot_b_on_an_stm32f405_sends_its_map_and_is_told_the_result() {
    let Some(data) = cosem_tests::real_data("kitti00") else { return };
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let (json, ok) =
        robots(&["--data", &data.display().to_string(), "--a", "0:5", "--b", "5:10", "--board-b", "stm32f405-sender"]);
    assert!(ok, "{json}");
    check_one_sided(&json);
}

#[test]
fn robot_b_on_an_stm32f405_matches_a_synthetic_street_with_no_prior() {
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let tmp = synthetic(10);
    let seq = tmp.path().join("seq").display().to_string();
    let (json, ok) =
        robots(&["--data", &seq, "--a", "0:5", "--b", "5:10", "--no-prior", "--board-b", "stm32f405-sender"]);
    assert!(ok, "{json}");
    check_one_sided(&json);
}

/// Both robots on STM32F405s, each within its 192 KiB (statics and peak
/// stack), at its own voxel size (0.7 m), with maps of its capacity.
fn check_stm32f405_pair(json: &Value) {
    for (i, r) in json["robots"].as_array().unwrap().iter().enumerate() {
        assert_eq!(r["board"], "stm32f405", "robot {i}: {r}");
        let ram = r["static_ram_bytes"].as_u64().unwrap() + r["peak_stack_bytes"].as_u64().unwrap();
        assert!(ram <= 192 * 1024, "robot {i} takes {ram} bytes of RAM with its stack");
        let voxels = r["map_voxels"].as_u64().unwrap();
        assert!(voxels > 2000 && voxels <= cosem_core::robot::Capacity::STM32F405.voxels as u64, "robot {i}: {r}");
    }
}

const STM32: [&str; 4] = ["--board-a", "stm32f405", "--board-b", "stm32f405"];

#[test]
fn two_stm32f405_robots_match_kitti00_on_board_with_and_without_a_prior() {
    let Some(data) = cosem_tests::real_data("kitti00") else { return };
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let data = data.display().to_string();
    for extra in [&[][..], &["--no-prior"][..], &["--no-prior", "--label-noise", "network"][..]] {
        let mut args = vec!["--data", &data, "--a", "0:5", "--b", "5:10"];
        args.extend_from_slice(&STM32);
        args.extend_from_slice(extra);
        let (json, ok) = robots(&args);
        assert!(ok, "{extra:?}: {json}");
        check_pair(&json);
        check_stm32f405_pair(&json);
    }
}

#[test]
fn two_stm32f405_robots_align_the_opposite_direction_loop_and_refuse_a_pair_that_shares_nothing() {
    let Some(loop08) = cosem_tests::real_data("kitti08-loop") else { return };
    let Some(loop00) = cosem_tests::real_data("kitti00-loop") else { return };
    if cosem_tests::firmware_elves().is_none() {
        return;
    }
    let loop08 = loop08.display().to_string();
    let mut args = vec!["--data", &loop08, "--a", "720:721", "--b", "1500:1501", "--no-prior"];
    args.extend_from_slice(&STM32);
    let (json, ok) = robots(&args);
    assert!(ok, "{json}");
    check_pair(&json);
    check_stm32f405_pair(&json);
    let loop00 = loop00.display().to_string();
    for noise in ["none", "network"] {
        let mut args = vec!["--data", &loop00, "--a", "88:89", "--b", "850:851", "--no-prior", "--label-noise", noise];
        args.extend_from_slice(&STM32);
        let (json, ok) = robots(&args);
        assert!(!ok, "{json}");
        check_stm32f405_pair(&json);
        for (i, r) in json["robots"].as_array().unwrap().iter().enumerate() {
            assert_eq!(r["status"], "NoOverlap", "{noise}: robot {i}: {r}");
            check_budget(i, r);
        }
    }
}
