//! The misuse table: every command of the test command's CLI, its cases
//! made from clap's own command tree (`cosem cli-tree`), so that no option
//! is forgotten: every number x {0, -1, NaN, inf, 1e308, u64 max}, every
//! frame range x {reversed, beyond, huge}, every input x {missing, empty,
//! unreadable, a folder, a dangling link, a looping link}, every output x
//! {an input, inside an input, `missing/..` of an input, a hard and a
//! symbolic link to an input}; and every output on a full disk (a small
//! tmpfs in a mount namespace where `unshare -m` works, else skipped and
//! counted) and under the writer's test-only cap (`COSEM_TEST_WRITE_CAP`).
//!
//! `cosem ros` cases run in a network namespace of their own with no
//! interface up (`unshare -n`), never on the machine's network; where one
//! cannot be made they are skipped and counted.
//!
//! Each case asserts: an exit within 30 s, no panic or signal; a refusal
//! names the argument or the file; every input identical afterwards
//! (content, mode, link target); nothing partial left beside the outputs.

use cosem_tests::{cosem_bin, cosem_ok};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The fixture every case reads: a small synthetic sequence with camera
/// segmentation, two maps of it, a class table.
struct Fixture {
    root: PathBuf,
    seq: PathBuf,
    a: PathBuf,
    b: PathBuf,
}

/// A valid, quick invocation of each command (`{SEQ}`, `{A}`, `{B}`, `{OUT}`
/// filled in); commands that need QEMU boards, a peer or the `segment`
/// feature run with what refuses or ends them quickly (after reading and
/// checking everything they are given).
fn baselines() -> BTreeMap<&'static str, &'static str> {
    BTreeMap::from([
        ("map", "map --data {SEQ} --frames 0:2 -o {OUT}/m.cmap"),
        ("match", "match {A} {B}"),
        ("eval", "eval --data {SEQ} --a 0:1 --b 1:2 --grid-stride 11 --limit 2 --threads 1"),
        ("link", "link --map {A} --listen 0 --accept-timeout 1"),
        ("relay", "relay --accept-timeout 1"),
        ("team", "team --robot {SEQ}:0:2 --robot {SEQ}:1:3"),
        ("session", "session --robot {SEQ}:0:2 --robot {SEQ}:1:3 --every 1"),
        ("info", "info {A}"),
        ("export ply", "export ply {A} -o {OUT}/m.ply"),
        ("export scans", "export scans --data {SEQ} --frames 0:2 --format pcd -o {OUT}/scans"),
        ("export mcap", "export mcap --data {SEQ} --frames 0:2 -o {OUT}/r.mcap"),
        ("label", "label --data {SEQ} --seg {SEQ}/seg_2 --frames 0:2 --out {OUT}/lab"),
        ("segment", "segment --model {A} --images {SEQ}/seg_2 --out {OUT}/seg"),
        ("synth", "synth --out {OUT}/syn --frames 2"),
        ("bench map", "bench map --data {SEQ} --frames 0:2 --repeat 1"),
        ("bench wire", "bench wire --data {SEQ} --frames 0:2 --repeat 1"),
        ("bench link", "bench link --data {SEQ} --a 0:1 --b 1:2 --seeds 1 --error-rates 0"),
        ("bench global", "bench global --data {SEQ} --a 0:1 --b 1:2 --repeat 1"),
        ("bench label", "bench label --frames 4 --seeds 1 --grid-stride 11"),
        ("bench segment", "bench segment --model {A} --images {SEQ}/seg_2 --frames 0:1"),
        ("bench session", "bench session --seeds 1 --frames 4 --threads 1"),
        ("demo", "demo --frames 4"),
        // Everything up to the boards (feeds, the host's twin run), then a
        // firmware that is not an ELF ends it before QEMU starts.
        ("robots", "robots --data {SEQ} --a 0:1 --b 1:2 --firmware {A}"),
        // Run in a network namespace of its own (`run`).
        ("ros play", "ros play --robot {SEQ}:0:2 --delay 0 --domain 7"),
        // Ends once nothing came for a second.
        ("ros node", "ros node --domain 7 --idle 1"),
    ])
}

const NUMBERS: [&str; 6] = ["0", "-1", "NaN", "inf", "1e308", "18446744073709551615"];
const RANGES: [(&str, &str); 3] = [("reversed", "5:2"), ("beyond", "0:100000"), ("huge", "0:18446744073709551615")];

/// One run of the table.
#[derive(Clone, Debug)]
struct Case {
    command: String,
    what: String,
    args: Vec<String>,
    /// Strings one of which a refusal must name.
    names: Vec<String>,
    env: Vec<(String, String)>,
    /// A folder whose listing must be the same after a failed run.
    watch: Option<PathBuf>,
}

fn fill(template: &str, f: &Fixture, out: &Path) -> Vec<String> {
    template
        .split_whitespace()
        .map(|w| {
            w.replace("{SEQ}", &f.seq.display().to_string())
                .replace("{A}", &f.a.display().to_string())
                .replace("{B}", &f.b.display().to_string())
                .replace("{OUT}", &out.display().to_string())
        })
        .collect()
}

/// `args` with the option `flag` set to `value` (replacing a value the
/// baseline gives it; a positional argument by its place).
fn with(args: &[String], arg: &Value, value: &str, baseline_positionals: usize) -> Vec<String> {
    let mut out = args.to_vec();
    let long = arg["long"].as_str().map(|l| format!("--{l}"));
    let short = arg["short"].as_str().map(|s| format!("-{s}"));
    let multiple = arg["multiple"].as_bool().unwrap_or(false);
    let flags: Vec<&String> = long.iter().chain(short.iter()).collect();
    if arg["positional"].as_bool().unwrap_or(false) {
        // The n-th positional of the baseline (after the command words).
        let index = arg["index"].as_u64().unwrap_or(0) as usize;
        let mut seen = 0;
        let mut i = 0;
        while i < out.len() {
            if out[i].starts_with('-') {
                i += 2;
                continue;
            }
            if seen == index && i >= baseline_positionals {
                out[i] = value.to_string();
                return out;
            }
            seen += 1;
            i += 1;
        }
        out.push(value.to_string());
        return out;
    }
    if let Some(i) = out.iter().position(|a| flags.contains(&a)) {
        out[i + 1] = value.to_string();
        return out;
    }
    let flag = long.or(short).unwrap_or_default();
    out.push(flag);
    out.push(value.to_string());
    if multiple && arg["id"] == "ports" {
        out.push(value.to_string());
    }
    out
}

/// A file's identity for the comparison: content hash, mode, link target.
fn snapshot(root: &Path) -> BTreeMap<PathBuf, String> {
    use std::os::unix::fs::PermissionsExt;
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            let Ok(meta) = std::fs::symlink_metadata(&p) else {
                out.insert(p, "vanished while listed".into());
                continue;
            };
            let id = if meta.file_type().is_symlink() {
                format!("link {}", std::fs::read_link(&p).map(|l| l.display().to_string()).unwrap_or_default())
            } else if meta.is_dir() {
                stack.push(p.clone());
                format!("dir {:o}", meta.permissions().mode())
            } else {
                let bytes = std::fs::read(&p).unwrap_or_default();
                let mut h: u64 = 0xcbf29ce484222325;
                for b in &bytes {
                    h = (h ^ u64::from(*b)).wrapping_mul(0x100000001b3);
                }
                format!("file {:o} {} {h:016x}", meta.permissions().mode(), bytes.len())
            };
            out.insert(p, id);
        }
    }
    out
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|d| d.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

/// What one case did.
struct Outcome {
    code: Option<i32>,
    stderr: String,
    secs: f64,
}

fn run(args: &[String], env: &[(String, String)], cwd: &Path) -> Outcome {
    let t = Instant::now();
    // DDS never on the machine's network: `ros` in a namespace of its own.
    let mut cmd = if args.first().is_some_and(|a| a == "ros") {
        let mut c = Command::new("unshare");
        c.arg("-n").arg(cosem_bin());
        c
    } else {
        Command::new(cosem_bin())
    };
    cmd.args(args).current_dir(cwd).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::piped());
    cmd.env("COSEM_DATA", cwd.join("no-data"));
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().expect("run cosem");
    let stderr = child.stderr.take();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        if let Some(mut e) = stderr {
            use std::io::Read;
            let _ = e.read_to_string(&mut s);
        }
        s
    });
    let code = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status.code();
        }
        if t.elapsed() > Duration::from_secs(30) {
            let _ = child.kill();
            let _ = child.wait();
            break Some(-999);
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    Outcome { code, stderr: reader.join().unwrap_or_default(), secs: t.elapsed().as_secs_f64() }
}

/// A run's first error line, its work folder spelled WORK (to compare runs).
fn first_error(o: &Outcome, work: &Path) -> String {
    o.stderr.lines().find(|l| l.starts_with("error")).unwrap_or("").replace(&work.display().to_string(), "WORK")
}

fn fixture(root: &Path) -> Fixture {
    let s = |p: &Path| p.display().to_string();
    let seq = root.join("in/seq");
    cosem_ok(&["synth", "--out", &s(&seq), "--frames", "3", "--seg", "cityscapes"]);
    let (a, b) = (root.join("in/a.cmap"), root.join("in/b.cmap"));
    cosem_ok(&["map", "--data", &s(&seq), "--frames", "0:2", "-o", &s(&a)]);
    cosem_ok(&["map", "--data", &s(&seq), "--frames", "1:3", "-o", &s(&b)]);
    Fixture { root: root.to_path_buf(), seq, a, b }
}

/// The command's own input: the baseline's first path in the fixture (a
/// robot's `PATH:START:END` is its folder).
fn own_input(f: &Fixture, base: &[String]) -> Option<PathBuf> {
    let inside = f.root.join("in").display().to_string();
    let arg = base.iter().find(|a| a.starts_with(&inside))?;
    let mut path = arg.as_str();
    while !Path::new(path).exists() {
        path = path.rsplit_once(':')?.0;
    }
    Some(PathBuf::from(path))
}

/// An output spelled as `input`: itself, inside it, `missing/..` of it, a
/// hard link (a folder: a symbolic one) and a symbolic link to it.
fn output_spellings(input: &Path, work: &Path) -> [(&'static str, String); 5] {
    let file = input.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let hard = if input.is_dir() { work.join("sym") } else { work.join("hard") };
    [
        ("an input", input.display().to_string()),
        ("inside an input", input.join("x").display().to_string()),
        ("missing/.. of an input", format!("{}/missing/../{file}", input.parent().unwrap().display())),
        ("a hard link to an input", hard.display().to_string()),
        ("a symbolic link to an input", work.join("sym").display().to_string()),
    ]
}

/// The table's cases for one command.
fn cases(f: &Fixture, command: &[String], args: &[Value], template: &str, work: &Path) -> Vec<Case> {
    let name = command.join(" ");
    let base = fill(template, f, &work.join("OUT"));
    let words = command.len();
    // Commands that read no file (synth, demo) have no input to protect.
    let has_inputs = args.iter().any(|a| a["kind"] == "input");
    let out = std::cell::RefCell::new(Vec::new());
    let case = |what: String, args: Vec<String>, names: Vec<String>| {
        out.borrow_mut().push(Case { command: name.clone(), what, args, names, env: Vec::new(), watch: None });
    };
    for arg in args {
        let long = arg["long"]
            .as_str()
            .map(|l| format!("--{l}"))
            .unwrap_or_else(|| arg["id"].as_str().unwrap_or("").to_uppercase());
        let id = arg["id"].as_str().unwrap_or("").to_string();
        let mut names = vec![long.clone(), id.replace('_', "-")];
        match arg["kind"].as_str().unwrap_or("") {
            "number" => {
                for v in NUMBERS {
                    names.push(v.to_string());
                    case(format!("{long} {v}"), with(&base, arg, v, words), names.clone());
                }
            }
            "range" => {
                for (what, v) in RANGES {
                    names.push(v.to_string());
                    case(format!("{long} {what} ({v})"), with(&base, arg, v, words), names.clone());
                }
            }
            "input" => {
                let bad = work.join("bad");
                let inputs: [(&str, PathBuf); 6] = [
                    ("missing", bad.join("missing")),
                    ("empty", bad.join("empty")),
                    ("unreadable", bad.join("unreadable")),
                    ("a folder", bad.join("folder")),
                    ("a dangling link", bad.join("dangling")),
                    ("a looping link", bad.join("loop")),
                ];
                for (what, p) in inputs {
                    let mut names = names.clone();
                    names.push(p.display().to_string());
                    names.push(p.file_name().unwrap().to_string_lossy().into_owned());
                    case(format!("{long} {what}"), with(&base, arg, &p.display().to_string(), words), names);
                }
            }
            "output" if !has_inputs => {}
            "output" => {
                let Some(input) = own_input(f, &base) else { continue };
                for (what, p) in output_spellings(&input, work) {
                    let mut names = names.clone();
                    names.push(p.clone());
                    case(format!("{long} {what}"), with(&base, arg, &p, words), names);
                }
                // Out of space: the writer's test cap (and a full tmpfs below).
                let mut names = names.clone();
                names.push("No space left".into());
                names.push(work.join("OUT").display().to_string());
                out.borrow_mut().push(Case {
                    command: name.clone(),
                    what: format!("{long} out of space (write cap)"),
                    args: base.clone(),
                    names,
                    env: vec![("COSEM_TEST_WRITE_CAP".into(), "1000".into())],
                    watch: Some(work.join("OUT")),
                });
            }
            _ => {}
        }
    }
    out.into_inner()
}

fn prepare_work(work: &Path, f: &Fixture, input: Option<&Path>) {
    std::fs::create_dir_all(work.join("OUT")).unwrap();
    let bad = work.join("bad");
    std::fs::create_dir_all(bad.join("folder")).unwrap();
    std::fs::write(bad.join("empty"), b"").unwrap();
    std::fs::write(bad.join("unreadable"), b"secret").unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(bad.join("unreadable"), std::fs::Permissions::from_mode(0o000)).unwrap();
    std::os::unix::fs::symlink(bad.join("nowhere"), bad.join("dangling")).unwrap();
    std::os::unix::fs::symlink(bad.join("loop"), bad.join("loop")).unwrap();
    let input = input.unwrap_or(&f.a);
    if input.is_file() {
        std::fs::hard_link(input, work.join("hard")).unwrap();
    }
    std::os::unix::fs::symlink(input, work.join("sym")).unwrap();
}

/// Whether a file of mode 000 is unreadable here (it is not to root).
fn unreadable_bites(scratch: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt;
    let p = scratch.join("mode-000-probe");
    std::fs::write(&p, b"x").unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o000)).unwrap();
    let bites = std::fs::File::open(&p).is_err();
    let _ = std::fs::remove_file(&p);
    bites
}

/// Whether `unshare -m` works here (root in a kernel that allows it).
fn can_unshare() -> bool {
    can_unshare_with("-m")
}

/// Whether `unshare FLAG` works here.
fn can_unshare_with(flag: &str) -> bool {
    Command::new("unshare")
        .args([flag, "true"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

#[test]
fn every_command_refuses_misuse_cleanly() {
    let tmp = tempfile::tempdir().unwrap();
    let f = fixture(tmp.path());
    let tree: Vec<Value> = serde_json::from_str(&cosem_ok(&["cli-tree"])).expect("cli-tree JSON");
    let (all, skipped) = table(&f, &tree, tmp.path());
    let checker = Checker {
        f: &f,
        spelled: tmp.path().join("work").display().to_string(),
        baseline_end: baseline_ends(&f),
        before: snapshot(&f.root.join("in")),
    };
    // Each case runs in a work folder of its own (outputs, bad inputs).
    let failures = Mutex::new(Vec::new());
    let next = Mutex::new(all.clone().into_iter());
    let t = Instant::now();
    let slowest = Mutex::new((0.0f64, String::new()));
    std::thread::scope(|s| {
        for _ in 0..4 {
            s.spawn(|| loop {
                let Some((k, case)) = next.lock().unwrap().next() else { break };
                let (secs, failed) = checker.check(k, &case);
                let mut sl = slowest.lock().unwrap();
                if secs > sl.0 {
                    *sl = (secs, format!("{} {}", case.command, case.what));
                }
                failures.lock().unwrap().extend(failed);
            });
        }
    });
    let failures = failures.into_inner().unwrap();
    let (secs, which) = slowest.into_inner().unwrap();
    println!(
        "misuse table: {} cases over {} commands in {:.1} s (slowest {secs:.1} s: {which}); {} failed",
        all.len(),
        tree.len(),
        t.elapsed().as_secs_f64(),
        failures.len()
    );
    if !skipped.is_empty() {
        println!(
            "misuse table: {} cases skipped (\"unreadable input\": a file of mode 000 is readable here, as root): {}",
            skipped.len(),
            skipped.join(", ")
        );
    }
    assert!(failures.is_empty(), "{} of {} cases failed:\n{}", failures.len(), all.len(), failures.join("\n"));
}

/// Every command's cases, numbered, and those skipped (with why).
fn table(f: &Fixture, tree: &[Value], scratch: &Path) -> (Vec<(usize, Case)>, Vec<String>) {
    let baselines = baselines();
    let (mut all, mut skipped) = (Vec::new(), Vec::new());
    for c in tree {
        let command: Vec<String> =
            c["command"].as_array().unwrap().iter().map(|w| w.as_str().unwrap().to_string()).collect();
        let name = command.join(" ");
        let template = baselines.get(name.as_str()).unwrap_or_else(|| panic!("no baseline for `{name}`: add one"));
        let mut args: Vec<Value> = c["args"].as_array().unwrap().clone();
        let mut positional = 0;
        for a in &mut args {
            if a["positional"].as_bool().unwrap_or(false) {
                a["index"] = positional.into();
                positional += 1;
            }
        }
        for case in cases(f, &command, &args, template, &scratch.join("work")) {
            if command[0] == "ros" && !can_unshare_with("-n") {
                skipped.push(format!("{name} [{}] (no network namespace: unshare -n)", case.what));
                continue;
            }
            if case.what.ends_with(" unreadable") && !unreadable_bites(scratch) {
                skipped.push(format!("{name} [{}]", case.what));
                continue;
            }
            all.push((all.len(), case));
        }
    }
    (all, skipped)
}

/// Each command's baseline alone, how it ended: a case that fails as its
/// baseline does (a link with no peer) is not a refusal of the case's value.
fn baseline_ends(f: &Fixture) -> BTreeMap<String, (Option<i32>, String)> {
    let mut ends = BTreeMap::new();
    for (name, template) in &baselines() {
        let work = f.root.join("base");
        prepare_work(&work, f, None);
        let o = run(&fill(template, f, &work.join("OUT")), &[], &work);
        ends.insert(name.to_string(), (o.code, first_error(&o, &work)));
        let _ = std::fs::remove_dir_all(&work);
    }
    ends
}

/// What every case is checked against.
struct Checker<'a> {
    f: &'a Fixture,
    /// The work folder as the cases spell it (each runs in its own).
    spelled: String,
    baseline_end: BTreeMap<String, (Option<i32>, String)>,
    /// The inputs before any case ran.
    before: BTreeMap<PathBuf, String>,
}

impl Checker<'_> {
    /// Runs case `k` in a work folder of its own: its time, and a line
    /// saying what went wrong (none when nothing did).
    fn check(&self, k: usize, case: &Case) -> (f64, Option<String>) {
        let (f, inputs) = (self.f, self.f.root.join("in"));
        let work = f.root.join(format!("w{k}"));
        let here = |a: &String| a.replace(&self.spelled, &work.display().to_string());
        let input = own_input(f, &case.args);
        prepare_work(&work, f, input.as_deref().filter(|p| p.exists()));
        let args: Vec<String> = case.args.iter().map(here).collect();
        let watch = case.watch.as_ref().map(|_| work.join("OUT"));
        let listed = watch.as_deref().map(listing);
        let parent = listing(&inputs);
        let o = run(&args, &case.env, &work);
        let mut problems = Vec::new();
        if o.code == Some(-999) {
            problems.push("did not end within 30 s".to_string());
        }
        if o.code.is_none() || o.code == Some(101) || o.stderr.contains("panicked") {
            problems.push(format!("crashed (exit {:?})", o.code));
        }
        let as_baseline = self.baseline_end.get(&case.command) == Some(&(o.code, first_error(&o, &work)));
        if o.code != Some(0) && o.code != Some(-999) && !as_baseline {
            let names: Vec<String> = case.names.iter().map(here).collect();
            if !names.iter().any(|n| !n.is_empty() && o.stderr.contains(n.as_str())) {
                problems.push(format!("the message names none of {names:?}"));
            }
            if let (Some(w), Some(l)) = (&watch, &listed) {
                if &listing(w) != l {
                    problems.push(format!("left {:?} in {}", listing(w), w.display()));
                }
            }
        }
        if listing(&inputs) != parent {
            problems.push(format!("the input folder now lists {:?}", listing(&inputs)));
        }
        let now = snapshot(&inputs);
        if now != self.before {
            let changed: Vec<_> =
                now.iter().filter(|(p, v)| self.before.get(*p) != Some(v)).map(|(p, _)| p.clone()).collect();
            problems.push(format!("an input changed: {changed:?}"));
        }
        let _ = std::fs::remove_dir_all(&work);
        let first = o.stderr.lines().next().unwrap_or("");
        let failed = (!problems.is_empty()).then(|| {
            format!("cosem {} [{}]: {} (exit {:?}: {first})", case.command, case.what, problems.join("; "), o.code)
        });
        (o.secs, failed)
    }
}

/// Every output on a full disk: a 64 KiB tmpfs in a mount namespace of the
/// run's own; the command fails naming the output and leaves nothing there.
#[test]
fn outputs_on_a_full_disk_fail_cleanly() {
    if !can_unshare() {
        println!("full disk: skipped 1 of 1 (unshare -m is not possible here)");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let f = fixture(tmp.path());
    let small = tmp.path().join("small");
    std::fs::create_dir_all(&small).unwrap();
    let runs = [
        "map --data {SEQ} --frames 0:2 -o {OUT}/m.cmap",
        "export ply {A} -o {OUT}/m.ply",
        "export scans --data {SEQ} --frames 0:2 --format pcd -o {OUT}/scans",
        "export mcap --data {SEQ} --frames 0:2 -o {OUT}/r.mcap",
        "label --data {SEQ} --seg {SEQ}/seg_2 --frames 0:2 --out {OUT}/lab",
        "synth --out {OUT}/syn --frames 2",
        "eval --data {SEQ} --a 0:1 --b 1:2 --limit 2 --threads 1 --json {OUT}/e.json",
    ];
    let before = snapshot(&f.root.join("in"));
    let mut failures = Vec::new();
    for template in runs {
        let args = fill(template, &f, &small);
        let script = format!(
            "mount -t tmpfs -o size=64k tmpfs '{d}' && head -c 64000 /dev/zero > '{d}/.fill' 2>/dev/null; \
             '{bin}' {args} > /dev/null; code=$?; echo \"exit=$code\"; ls -A '{d}' | grep -vx .fill",
            d = small.display(),
            bin = cosem_bin().display(),
            args = args.iter().map(|a| format!("'{a}'")).collect::<Vec<_>>().join(" ")
        );
        let out = Command::new("unshare").args(["-m", "sh", "-c", &script]).output().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        let code = stdout.lines().find_map(|l| l.strip_prefix("exit=")).unwrap_or("?").to_string();
        let left: Vec<&str> = stdout.lines().filter(|l| !l.starts_with("exit=") && !l.is_empty()).collect();
        let ok = code == "1"
            && left.is_empty()
            && stderr.contains(&small.display().to_string())
            && !stderr.contains("panicked");
        if !ok {
            failures.push(format!("cosem {template}: exit {code}, left {left:?}: {}", stderr.trim()));
        }
    }
    assert_eq!(snapshot(&f.root.join("in")), before, "an input changed");
    println!("full disk: {} commands, {} failed", runs.len(), failures.len());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
