//! Output paths checked against inputs: no command writes over what it
//! reads, whatever the spelling (absolute, relative, `..`, symbolic links).

use std::path::{Path, PathBuf};

/// A path with its existing part resolved (symbolic links, `..`): two
/// spellings of one folder compare equal, whether or not it exists yet.
pub fn resolved(path: &Path) -> PathBuf {
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().map(|d| d.join(path)).unwrap_or_else(|_| path.to_path_buf())
    };
    let mut rest = Vec::new();
    let mut at = abs.as_path();
    loop {
        if let Ok(c) = std::fs::canonicalize(at) {
            return rest.iter().rev().fold(c, |p, part| p.join(part));
        }
        match (at.parent(), at.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                at = parent;
            }
            _ => return abs,
        }
    }
}

/// Refuses to write `out` when it is one of `inputs` (the same file by any
/// spelling).
pub fn refuse_overwrite(out: &Path, inputs: &[&Path]) -> Result<(), crate::Error> {
    let o = resolved(out);
    match inputs.iter().find(|i| resolved(i) == o) {
        Some(i) => Err(crate::Error::Invalid(format!(
            "{}: is the input {}: an input is never overwritten, choose another output",
            out.display(),
            i.display()
        ))),
        None => Ok(()),
    }
}

/// Refuses to write `out` inside one of the input `folders`.
pub fn refuse_inside(out: &Path, folders: &[&Path]) -> Result<(), crate::Error> {
    let o = resolved(out);
    match folders.iter().find(|f| o.starts_with(resolved(f))) {
        Some(f) => Err(crate::Error::Invalid(format!(
            "{}: lies in the input folder {}: an input folder is never written, choose another output",
            out.display(),
            f.display()
        ))),
        None => Ok(()),
    }
}

/// Checks, before a long run, that every output can be written and lies in
/// no input folder (leaving behind no file that was not there).
pub fn check_outputs(outputs: &[&Path], input_folders: &[&Path]) -> Result<(), crate::Error> {
    for path in outputs {
        refuse_inside(path, input_folders)?;
        let existed = path.exists();
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(|source| crate::Error::Io { path: path.to_path_buf(), source })?;
        if !existed {
            let _ = std::fs::remove_file(path);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spellings_of_one_path_are_one() {
        let tmp = std::env::temp_dir().join(format!("cosem-paths-{}", std::process::id()));
        std::fs::create_dir_all(tmp.join("a")).unwrap();
        std::fs::write(tmp.join("a/m.cmap"), b"x").unwrap();
        let plain = tmp.join("a/m.cmap");
        assert_eq!(resolved(&tmp.join("a/../a/m.cmap")), resolved(&plain));
        assert_eq!(resolved(&tmp.join("a/new/deeper")), resolved(&tmp.join("a")).join("new/deeper"));
        assert!(refuse_overwrite(&tmp.join("a/./m.cmap"), &[&plain]).is_err());
        assert!(refuse_overwrite(&tmp.join("a/other.ply"), &[&plain]).is_ok());
        assert!(refuse_inside(&tmp.join("a/x/../y.cmap"), &[&tmp.join("a")]).is_err());
        assert!(refuse_inside(&tmp.join("b.cmap"), &[&tmp.join("a")]).is_ok());
        let _ = std::fs::remove_dir_all(&tmp);
    }
}
