//! Output paths checked against inputs: no command writes over what it
//! reads, whatever the spelling (absolute, relative, `..`, symbolic links,
//! hard links: files are compared by device and inode as well as by
//! path). Outputs are written to a temporary file in the destination
//! folder and renamed into place on success ([`Output`]), so a refused or
//! failed command never truncates anything.

use std::io::Write;
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

/// An existing file's identity: (device, inode).
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

/// Whether `a` and `b` are one file: the same resolved path, or the same
/// device and inode (a hard link, a bind mount).
pub fn same_file(a: &Path, b: &Path) -> bool {
    if resolved(a) == resolved(b) {
        return true;
    }
    matches!((file_id(a), file_id(b)), (Some(x), Some(y)) if x == y)
}

/// Refuses to write `out` when it is one of `inputs` (the same file by any
/// spelling, or through a hard link).
pub fn refuse_overwrite(out: &Path, inputs: &[&Path]) -> Result<(), crate::Error> {
    match inputs.iter().find(|i| same_file(out, i)) {
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

/// An output file being written: a new temporary file beside `path`,
/// renamed onto it by [`Output::commit`]; dropped uncommitted (an error on
/// the way), the temporary file is removed and `path` is untouched. A
/// device or FIFO (e.g. `/dev/stdout`) is written in place, never replaced
/// by a file; a folder is refused.
pub struct Output {
    path: PathBuf,
    tmp: Option<PathBuf>,
    file: std::io::BufWriter<std::fs::File>,
}

impl Output {
    /// Starts writing `path`.
    pub fn create(path: &Path) -> std::io::Result<Self> {
        let meta = std::fs::metadata(path).ok();
        if meta.as_ref().is_some_and(|m| m.is_dir()) {
            return Err(std::io::Error::new(std::io::ErrorKind::IsADirectory, "is a folder, not a file"));
        }
        if meta.as_ref().is_some_and(|m| !m.is_file()) {
            let file = std::fs::OpenOptions::new().write(true).open(path)?;
            return Ok(Output { path: path.to_owned(), tmp: None, file: std::io::BufWriter::new(file) });
        }
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "output".into());
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        if !dir.is_dir() {
            let what = format!("the folder {} does not exist", dir.display());
            return Err(std::io::Error::new(std::io::ErrorKind::NotFound, what));
        }
        static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let mut k = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        loop {
            let tmp = dir.join(format!(".{name}.cosem-{}-{k}.tmp", std::process::id()));
            match std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
                Ok(file) => {
                    return Ok(Output { path: path.to_owned(), tmp: Some(tmp), file: std::io::BufWriter::new(file) })
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && k < u32::MAX => k += 1,
                Err(e) => return Err(e),
            }
        }
    }

    /// Finishes: flushes and renames the file into place.
    pub fn commit(mut self) -> std::io::Result<()> {
        self.file.flush()?;
        if let Some(tmp) = self.tmp.take() {
            if let Err(e) = std::fs::rename(&tmp, &self.path) {
                let _ = std::fs::remove_file(&tmp);
                return Err(e);
            }
        }
        Ok(())
    }
}

impl Write for Output {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.file.write(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl std::io::Seek for Output {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        self.file.seek(pos)
    }
}

impl Drop for Output {
    fn drop(&mut self) {
        if let Some(tmp) = self.tmp.take() {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

/// Writes `bytes` to `path` through an [`Output`] (all or nothing).
pub fn write_file(path: impl AsRef<Path>, bytes: impl AsRef<[u8]>) -> std::io::Result<()> {
    let mut out = Output::create(path.as_ref())?;
    out.write_all(bytes.as_ref())?;
    out.commit()
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
        // A hard link is the same file under another name.
        std::fs::hard_link(&plain, tmp.join("linked.cmap")).unwrap();
        assert!(refuse_overwrite(&tmp.join("linked.cmap"), &[&plain]).is_err());
        let _ = std::fs::remove_dir_all(&tmp);
    }

    #[test]
    fn outputs_are_all_or_nothing() {
        let tmp = std::env::temp_dir().join(format!("cosem-output-{}", std::process::id()));
        std::fs::create_dir_all(&tmp).unwrap();
        let path = tmp.join("m.cmap");
        std::fs::write(&path, b"old").unwrap();
        {
            let mut out = Output::create(&path).unwrap();
            out.write_all(b"half").unwrap();
            // Dropped uncommitted: the old file stays, no temporary is left.
        }
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
        write_file(&path, b"new").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        assert_eq!(std::fs::read_dir(&tmp).unwrap().count(), 1);
        assert!(Output::create(&tmp).is_err());
        // A device is written in place, not replaced by a file.
        write_file(Path::new("/dev/null"), b"x").unwrap();
        assert!(!std::fs::metadata("/dev/null").unwrap().is_file());
        let _ = std::fs::remove_dir_all(&tmp);
    }
}
