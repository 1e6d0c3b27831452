//! The core's modules import only downward: each module may use the
//! modules of lower layers, never a higher one (nor a module of its own
//! layer), so the layers in docs/architecture.md stay true. Read from the
//! sources: code lines before a file's `#[cfg(test)]`, comments and
//! documentation links left out, test-only files skipped.

use std::path::Path;

/// The layers, lowest first: a module may import those of lower layers.
const LAYERS: &[(&str, u32)] = &[
    ("geometry", 0),
    ("region", 0),
    ("classes", 1),
    ("map", 2),
    // Camera labels become a map's label evidence.
    ("camera", 3),
    ("wire", 4),
    ("link", 5),
    ("matching", 6),
    ("team", 6),
    ("selftest", 7),
    ("robot", 8),
    // Tests and hosts only (feature `sim`): lines and the driver of robots.
    ("sim", 9),
];

fn layer(module: &str) -> Option<u32> {
    LAYERS.iter().find(|(m, _)| *m == module).map(|l| l.1)
}

fn files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn core_modules_import_only_lower_layers() {
    let src = cosem_tests::workspace_root().join("core/src");
    let mut all = Vec::new();
    files(&src, &mut all);
    let mut wrong = Vec::new();
    for path in &all {
        let rel = path.strip_prefix(&src).unwrap();
        let name = rel.file_stem().unwrap().to_string_lossy();
        if name == "tests" || name == "test_util" || name == "lib" {
            continue;
        }
        // The module a file belongs to: its first path component.
        let top = rel.components().next().unwrap().as_os_str().to_string_lossy();
        let module = top.trim_end_matches(".rs").to_string();
        let Some(own) = layer(&module) else {
            wrong.push(format!("{}: module `{module}` has no layer in this test", rel.display()));
            continue;
        };
        let text = std::fs::read_to_string(path).unwrap();
        for (n, line) in text.lines().enumerate() {
            let code = line.trim_start();
            if code.starts_with("#[cfg(test)]") {
                break;
            }
            if code.starts_with("//") {
                continue;
            }
            for (at, _) in code.match_indices("crate::") {
                let used: String = code[at + 7..].chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                if used == module || used == "test_util" {
                    continue;
                }
                match layer(&used) {
                    Some(l) if l < own => {}
                    None if used.is_empty() => wrong.push(format!(
                        "{}:{}: write `crate::module::...` paths, one module each (a grouped `crate::{{...}}` is not checked)",
                        rel.display(),
                        n + 1
                    )),
                    _ => wrong.push(format!("{}:{}: `{module}` uses `crate::{used}`", rel.display(), n + 1)),
                }
            }
        }
    }
    assert!(wrong.is_empty(), "imports against the layers:\n{}", wrong.join("\n"));
}
