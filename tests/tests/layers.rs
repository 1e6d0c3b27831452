//! Every crate's modules import only downward, so the layers in
//! docs/architecture.md stay true: a module may use the modules of lower
//! layers, never a higher one; inside one layer (a folder, or the core's
//! own modules of one layer) imports are allowed where they form no cycle.
//!
//! Read from the sources: code before a file's `#[cfg(test)]`, comments and
//! documentation left out, test-only files skipped. Every path that names a
//! module counts: `crate::a::b`, grouped `crate::{a, b::c}`, `super::`
//! resolved against the file's place, and `pub use` re-exports. The same
//! table is checked against docs/architecture.md's, and a fixture of
//! wrong imports must fail.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A crate's layers, lowest first: (layer name, its modules).
type Layers = &'static [(&'static str, &'static [&'static str])];

/// cosem-core: its top modules are its stages.
const CORE: Layers = &[
    ("base", &["geometry", "region"]),
    ("classes", &["classes"]),
    ("map", &["map"]),
    // Camera labels become a map's label evidence.
    ("camera", &["camera"]),
    ("wire", &["wire"]),
    ("link", &["link"]),
    ("matching", &["matching", "team", "pipeline", "session"]),
    ("selftest", &["selftest"]),
    ("robot", &["robot"]),
    // Tests and hosts only (feature `sim`): lines and the driver of robots.
    ("sim", &["sim"]),
];

/// cosem-host: files at the root are the base; folders are layers.
const HOST: Layers = &[
    // The one error carries a layer's typed error boxed: it names none.
    ("base", &["paths", "rng", "limits", "diagnostics", "knobs", "error", "poses"]),
    ("sources", &["sources"]),
    ("camera", &["camera"]),
    ("worlds", &["worlds"]),
    ("maps", &["maps"]),
    ("matching", &["matching"]),
    ("lines", &["lines"]),
    ("evaluation", &["evaluation"]),
    ("boards", &["boards"]),
    ("reports", &["reports"]),
    // ROS 2 over DDS: the live node and player (feature `ros`).
    ("ros", &["ros"]),
    // The `cosem` binary.
    ("cli", &["cli", "main"]),
];

fn layer_of(layers: Layers, module: &str) -> Option<usize> {
    layers.iter().position(|(_, ms)| ms.contains(&module))
}

/// A source file's module path inside its crate (`sources/kitti.rs` ->
/// `[sources, kitti]`, `map/mod.rs` -> `[map]`).
fn module_path(rel: &Path) -> Vec<String> {
    let mut parts: Vec<String> = rel.iter().map(|c| c.to_string_lossy().into_owned()).collect();
    if let Some(last) = parts.pop() {
        let stem = last.trim_end_matches(".rs").to_string();
        if stem != "mod" && stem != "lib" {
            parts.push(stem);
        }
    }
    parts
}

/// The code of a file that counts: without comments, and without the
/// item after each `#[cfg(test)]` (a test module, to its closing brace,
/// or a one-line item).
fn code(text: &str) -> String {
    let mut out = String::new();
    let (mut skipping, mut depth, mut opened) = (false, 0i32, false);
    for line in text.lines() {
        let t = line.trim_start();
        if t.starts_with("//") {
            continue;
        }
        if t.starts_with("#[cfg(test)]") {
            (skipping, depth, opened) = (true, 0, false);
            continue;
        }
        if skipping {
            for ch in t.chars() {
                match ch {
                    '{' => (depth, opened) = (depth + 1, true),
                    '}' => depth -= 1,
                    _ => {}
                }
            }
            if (opened && depth <= 0) || (!opened && t.ends_with(';')) {
                skipping = false;
            }
            continue;
        }
        let line = line.split(" //").next().unwrap_or("");
        out.push_str(line);
        out.push('\n');
    }
    out
}

fn ident(s: &str) -> String {
    s.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect()
}

/// Every module path a file's code names, absolute in its crate:
/// `crate::a::b` -> `[a, b]`, `crate::{a, b::c}` -> `[a]`, `[b, c]`,
/// `super::x` from `[a, b]` -> `[a, x]`.
fn named_paths(code: &str, own: &[String]) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let bytes = code.as_bytes();
    let mut i = 0;
    while i < code.len() {
        let rest = &code[i..];
        let preceded = i > 0 && (bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_' || bytes[i - 1] == b':');
        let (base, skip): (Vec<String>, usize) = if !preceded && rest.starts_with("crate::") {
            (Vec::new(), 7)
        } else if !preceded && rest.starts_with("super::") {
            // `super::super::...` climbs once per `super`.
            let mut base = own.to_vec();
            let mut skip = 0;
            while code[i + skip..].starts_with("super::") {
                base.pop();
                skip += 7;
            }
            (base, skip)
        } else {
            i += rest.chars().next().map_or(1, char::len_utf8);
            continue;
        };
        let after = &code[i + skip..];
        for tail in expand(after) {
            let mut p = base.clone();
            p.extend(tail);
            out.push(p);
        }
        i += skip;
    }
    out
}

/// The paths a `use` tail names: `a::b::C` -> `[a, b, C]`, `{a, b::c}` ->
/// `[a]`, `[b, c]` (groups nested to any depth).
fn expand(after: &str) -> Vec<Vec<String>> {
    let mut head = Vec::new();
    let mut s = after;
    loop {
        let s2 = s.trim_start();
        if let Some(inner) = s2.strip_prefix('{') {
            // The group's items, split at top-level commas.
            let mut depth = 0;
            let mut end = inner.len();
            for (k, ch) in inner.char_indices() {
                match ch {
                    '{' => depth += 1,
                    '}' if depth == 0 => {
                        end = k;
                        break;
                    }
                    '}' => depth -= 1,
                    _ => {}
                }
            }
            let body = &inner[..end];
            let (mut items, mut depth, mut start) = (Vec::new(), 0, 0);
            for (k, ch) in body.char_indices() {
                match ch {
                    '{' => depth += 1,
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        items.push(&body[start..k]);
                        start = k + 1;
                    }
                    _ => {}
                }
            }
            items.push(&body[start..]);
            let mut out = Vec::new();
            for item in items.into_iter().map(str::trim).filter(|t| !t.is_empty()) {
                for tail in expand(item) {
                    let mut p = head.clone();
                    p.extend(tail);
                    out.push(p);
                }
            }
            return out;
        }
        let name = ident(s2);
        if name.is_empty() {
            return vec![head];
        }
        if name != "self" {
            head.push(name.clone());
        }
        s = &s2[name.len()..];
        match s.strip_prefix("::") {
            Some(r) => s = r,
            None => return vec![head],
        }
    }
}

/// One file of a crate: its path inside `src/` and its text.
struct File {
    rel: PathBuf,
    text: String,
}

fn read_crate(src: &Path) -> Vec<File> {
    fn walk(dir: &Path, src: &Path, out: &mut Vec<File>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(&p, src, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let rel = p.strip_prefix(src).unwrap().to_path_buf();
                out.push(File { rel, text: std::fs::read_to_string(&p).unwrap() });
            }
        }
    }
    let mut out = Vec::new();
    walk(src, src, &mut out);
    out.sort_by(|a, b| a.rel.cmp(&b.rel));
    out
}

/// What is wrong with a crate's imports under `layers`: upward imports,
/// modules the table does not place, and cycles inside one layer.
fn check(layers: Layers, files: &[File]) -> Vec<String> {
    let mut wrong = Vec::new();
    // Edges between the units a layer holds: a folder's files (`[sources,
    // kitti]`), or a layer's top modules (core: `matching`, `team`).
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let modules: BTreeSet<Vec<String>> = files.iter().map(|f| module_path(&f.rel)).collect();
    for f in files {
        let own = module_path(&f.rel);
        let name = f.rel.file_stem().unwrap().to_string_lossy();
        if own.is_empty() || name == "tests" || name == "test_util" || own.iter().any(|p| p == "tests") {
            continue;
        }
        let top = own[0].clone();
        let Some(own_layer) = layer_of(layers, &top) else {
            wrong.push(format!("{}: module `{top}` has no layer in this test", f.rel.display()));
            continue;
        };
        for path in named_paths(&code(&f.text), &own) {
            let Some(used_top) = path.first() else { continue };
            let Some(used_layer) = layer_of(layers, used_top) else {
                if modules.iter().any(|m| m.first() == Some(used_top)) {
                    wrong.push(format!("{}: module `{used_top}` has no layer in this test", f.rel.display()));
                }
                continue;
            };
            if used_layer > own_layer {
                wrong.push(format!(
                    "{}: `{}` (layer {}) imports `{}` (layer {}, above it)",
                    f.rel.display(),
                    own.join("::"),
                    layers[own_layer].0,
                    path.join("::"),
                    layers[used_layer].0
                ));
            } else if used_layer == own_layer {
                let (from, to) = (unit(&own, &modules), unit(&path, &modules));
                if from != to {
                    edges.entry(from).or_default().insert(to);
                }
            }
        }
    }
    for cycle in cycles(&edges) {
        wrong.push(format!("a cycle inside one layer: {}", cycle.join(" -> ")));
    }
    wrong
}

/// The unit of a module path that cycles are counted between: a module
/// and the one right under it (`sources::kitti`, `matching::pyramid`), or
/// a top module alone when the path goes on to an item.
fn unit(path: &[String], modules: &BTreeSet<Vec<String>>) -> String {
    if path.len() >= 2 && modules.contains(&path[..2].to_vec()) {
        format!("{}::{}", path[0], path[1])
    } else {
        path[0].clone()
    }
}

/// The cycles of a directed graph, each once (as found by a depth-first
/// walk from its smallest node).
fn cycles(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    fn visit(
        n: &str,
        edges: &BTreeMap<String, BTreeSet<String>>,
        stack: &mut Vec<String>,
        done: &mut BTreeSet<String>,
        out: &mut Vec<Vec<String>>,
    ) {
        if let Some(at) = stack.iter().position(|s| s == n) {
            let mut c = stack[at..].to_vec();
            c.push(n.to_string());
            out.push(c);
            return;
        }
        if done.contains(n) {
            return;
        }
        stack.push(n.to_string());
        for m in edges.get(n).into_iter().flatten() {
            visit(m, edges, stack, done, out);
        }
        stack.pop();
        done.insert(n.to_string());
    }
    let (mut done, mut out) = (BTreeSet::new(), Vec::new());
    for n in edges.keys() {
        visit(n, edges, &mut Vec::new(), &mut done, &mut out);
    }
    out
}

#[test]
fn core_modules_import_only_lower_layers() {
    let files = read_crate(&cosem_tests::workspace_root().join("core/src"));
    let wrong = check(CORE, &files);
    assert!(wrong.is_empty(), "cosem-core imports against its layers:\n{}", wrong.join("\n"));
}

#[test]
fn host_modules_import_only_lower_layers() {
    let files = read_crate(&cosem_tests::workspace_root().join("host/src"));
    let wrong = check(HOST, &files);
    assert!(wrong.is_empty(), "cosem-host imports against its layers:\n{}", wrong.join("\n"));
}

/// The host's library is reached by its layer paths: no module is
/// re-exported under a flat name.
#[test]
fn host_library_has_no_flat_re_exports() {
    let lib = std::fs::read_to_string(cosem_tests::workspace_root().join("host/src/lib.rs")).unwrap();
    let flat: Vec<&str> = lib.lines().filter(|l| l.trim_start().starts_with("pub use")).collect();
    assert!(flat.is_empty(), "host/src/lib.rs re-exports: {flat:?}");
}

/// The check finds what it must: an upward import in each spelling, and a
/// cycle inside one layer.
#[test]
fn the_layer_check_fails_on_wrong_imports() {
    let file = |rel: &str, text: &str| File { rel: rel.into(), text: text.into() };
    let fixture = [
        file("paths.rs", "use crate::sources::kitti::Frame;\n"),
        file("rng.rs", ""),
        file("sources/kitti.rs", "use crate::{rng::Rng, maps::mapping};\nuse super::cloud::Cloud;\n"),
        file("sources/cloud.rs", "pub use crate::camera::label::LabelError;\nuse super::kitti::Frame;\n"),
        file("sources/frame.rs", "fn f() { super::super::maps::noise::apply(); }\n"),
        file("sources/source.rs", "use super::cloud::Cloud;\n"),
        file("sources/recording.rs", "// crate::boards::x in a comment\nfn g() {} // crate::boards::y\n"),
        file(
            "camera/label.rs",
            "use crate::sources::{kitti, cloud};\n#[cfg(test)]\nuse crate::maps::x;\n#[cfg(test)]\nmod tests {\n    \
             use crate::boards::y;\n}\nfn after() { crate::maps::z(); }\n",
        ),
        file("maps/mapping.rs", "use crate::sources::kitti::Frame;\n"),
        file("maps/noise.rs", "use crate::maps::mapping::HostMap;\n"),
        file("nowhere/x.rs", ""),
    ];
    let wrong = check(HOST, &fixture);
    let has = |s: &str| wrong.iter().any(|w| w.contains(s));
    assert!(has("paths.rs: `paths` (layer base) imports `sources::kitti::Frame`"), "{wrong:#?}");
    assert!(has("imports `maps::mapping` (layer maps"), "grouped: {wrong:#?}");
    assert!(has("imports `camera::label::LabelError`"), "re-export: {wrong:#?}");
    assert!(has("imports `maps::noise::apply`"), "super::super: {wrong:#?}");
    assert!(has("module `nowhere` has no layer"), "{wrong:#?}");
    assert!(has("a cycle inside one layer: sources::cloud -> sources::kitti -> sources::cloud"), "{wrong:#?}");
    assert!(!has("boards"), "a comment is not an import: {wrong:#?}");
    assert!(!has("maps::x") && !has("boards::y"), "test code is not checked: {wrong:#?}");
    assert!(has("imports `maps::z`"), "code after a test module is: {wrong:#?}");
    assert!(!has("`maps::noise` (layer maps) imports"), "same layer, no cycle: {wrong:#?}");
    assert_eq!(wrong.len(), 7, "{wrong:#?}");
}

/// docs/architecture.md lists each crate's layers as this test holds them:
/// a line `- <crate> layer <n> <name>: <modules>` per layer.
#[test]
fn architecture_doc_lists_the_same_layers() {
    let doc = std::fs::read_to_string(cosem_tests::workspace_root().join("docs/architecture.md")).unwrap();
    for (krate, layers) in [("core", CORE), ("host", HOST)] {
        let want: Vec<String> = layers
            .iter()
            .enumerate()
            .map(|(n, (name, ms))| format!("- {krate} layer {n} {name}: {}", ms.join(", ")))
            .collect();
        let prefix = format!("- {krate} layer ");
        let got: Vec<String> =
            doc.lines().filter(|l| l.starts_with(&prefix)).map(|l| l.trim_end().to_string()).collect();
        assert_eq!(got, want, "docs/architecture.md's {krate} layers differ from tests/tests/layers.rs");
    }
}

/// The lines of a library's code (comments and tests left out) that spell
/// a command-line flag (`--name`), other than arguments to another
/// program (cargo, QEMU).
fn flags_spelled(files: &[File]) -> Vec<String> {
    let mut out = Vec::new();
    for f in files {
        for line in code(&f.text).lines() {
            let foreign = line.contains("cargo build") || line.contains(".args([") || line.contains(".arg(");
            let spelled = line.match_indices("--").any(|(i, _)| {
                line[i + 2..].chars().next().is_some_and(|c| c.is_ascii_lowercase())
                    && !line[..i].ends_with(|c: char| c.is_alphanumeric() || c == '-')
            });
            if spelled && !foreign {
                out.push(format!("{}: {}", f.rel.display(), line.trim()));
            }
        }
    }
    out
}

/// The libraries speak types, not flags: a message names a setting (a
/// `knobs::Knob`, spelled by the front end) and its value; only the
/// command line (`host/src/cli`, `main.rs`) spells its flags.
#[test]
fn libraries_spell_no_flags() {
    let root = cosem_tests::workspace_root();
    let mut files: Vec<File> = read_crate(&root.join("host/src"))
        .into_iter()
        .filter(|f| !f.rel.starts_with("cli") && f.rel != Path::new("main.rs") && !f.rel.starts_with("bin"))
        .collect();
    files.extend(read_crate(&root.join("python/src")));
    files.extend(read_crate(&root.join("core/src")));
    let spelled = flags_spelled(&files);
    assert!(spelled.is_empty(), "library code spelling flags (name a knobs::Knob instead):\n{}", spelled.join("\n"));
    // The check itself: a flag in a message is caught, a cargo command is not.
    let fixture = File {
        rel: "maps/x.rs".into(),
        text: "fn f() -> String { format!(\"use --max-range\") }\nfn g() { c.args([\"build\", \"--release\"]); }\n"
            .into(),
    };
    assert_eq!(flags_spelled(&[fixture]).len(), 1);
}
