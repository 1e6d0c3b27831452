//! Outputs checked against inputs, and written all or nothing. One rule
//! for every command: an output is compared with every input (data
//! folders, models, images, calibration, class tables, earlier outputs
//! named as inputs) after resolving the longest existing ancestor of each
//! and normalising the rest (so `missing/../data` is `data` before
//! `missing` exists), and by device and inode (hard links, bind mounts).
//! An output may not be an input, lie inside one, or hold one (a folder
//! output is replaced whole). Files are written to a temporary file beside
//! them and renamed into place ([`Output`]); folders to a temporary sibling
//! folder swapped into place ([`OutputDir`]): a refused or failed command
//! leaves its output's folder as it found it.

use std::io::Write;
use std::path::{Component, Path, PathBuf};

/// How many symbolic links one path may pass through (as Linux's 40).
const MAX_LINKS: usize = 40;

/// A path with its existing part resolved (symbolic links, `..`) and the
/// rest normalised: two spellings of one file compare equal, whether or
/// not it exists yet. `a/missing/../b` is `a/b`, as it will be once
/// `missing` is created; a dangling symbolic link resolves to its target.
pub fn resolved(path: &Path) -> PathBuf {
    resolve_in(path, 0)
}

fn resolve_in(path: &Path, depth: usize) -> PathBuf {
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().map(|d| d.join(path)).unwrap_or_else(|_| path.to_path_buf())
    };
    let mut at = PathBuf::new();
    for part in abs.components() {
        match part {
            Component::Prefix(p) => at.push(p.as_os_str()),
            Component::RootDir => at.push("/"),
            Component::CurDir => {}
            // `at` has no links left in it: its parent is the real one.
            Component::ParentDir => {
                at.pop();
            }
            Component::Normal(name) => {
                at.push(name);
                let Ok(meta) = std::fs::symlink_metadata(&at) else { continue };
                if !meta.file_type().is_symlink() {
                    continue;
                }
                if let Ok(real) = std::fs::canonicalize(&at) {
                    at = real;
                } else if let (Ok(target), true) = (std::fs::read_link(&at), depth < MAX_LINKS) {
                    // Dangling: writing through it creates its target.
                    let base = at.parent().map(Path::to_path_buf).unwrap_or_default();
                    at = resolve_in(&base.join(target), depth + 1);
                }
            }
        }
    }
    at
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

/// Whether `inner` is `outer` or lies inside it, by resolved path or by
/// the identity of one of `inner`'s existing folders.
fn within(inner: &Path, outer: &Path) -> bool {
    let inner = resolved(inner);
    if inner.starts_with(resolved(outer)) {
        return true;
    }
    let Some(id) = file_id(outer) else { return false };
    inner.ancestors().any(|a| file_id(a) == Some(id))
}

/// How an output meets an input, if it does.
fn clash(out: &Path, input: &Path) -> Option<&'static str> {
    if same_file(out, input) {
        Some("is")
    } else if within(out, input) {
        Some("lies inside")
    } else if within(input, out) {
        Some("holds")
    } else {
        None
    }
}

/// The one path rule: refuses the output `out` (given as `arg`) when it
/// is, lies inside or holds one of `inputs` (each with its argument), or
/// one of the symbolic links found in an input folder (a few levels down)
/// points into it. The message names both arguments and both paths.
pub fn check_output(arg: &str, out: &Path, inputs: &[(&str, &Path)]) -> Result<(), crate::error::Error> {
    for (name, input) in inputs {
        if let Some(how) = clash(out, input) {
            return Err(refusal(arg, out, how, name, input));
        }
    }
    for (name, input) in inputs {
        if let Some(link) = link_into(input, out) {
            return Err(crate::error::Error::Invalid(format!(
                "{arg} {}: the input {name} {} holds {}, a link into it: an input is never written, choose another output",
                out.display(),
                input.display(),
                link.display()
            )));
        }
    }
    Ok(())
}

/// Refuses outputs that are, lie inside or hold one another (two outputs
/// of one command, such as a folder and a file written beside it).
pub fn check_outputs_apart(outputs: &[(&str, &Path)]) -> Result<(), crate::error::Error> {
    for (i, (a, pa)) in outputs.iter().enumerate() {
        for (b, pb) in &outputs[i + 1..] {
            if let Some(how) = clash(pa, pb) {
                return Err(crate::error::Error::Invalid(format!(
                    "{a} {}: {how} the output {b} {}: give each output its own place",
                    pa.display(),
                    pb.display()
                )));
            }
        }
    }
    Ok(())
}

fn refusal(arg: &str, out: &Path, how: &str, name: &str, input: &Path) -> crate::error::Error {
    let what = match how {
        "is" => "an input is never written (never overwritten)",
        "lies inside" => "an input folder is never written",
        _ => "replacing it would remove an input, and an input is never written",
    };
    crate::error::Error::Invalid(format!(
        "{arg} {}: {how} the input {name} {}: {what}, choose another output",
        out.display(),
        input.display()
    ))
}

/// How deep and how many entries [`link_into`] looks through.
const LINK_SCAN_DEPTH: usize = 3;
const LINK_SCAN_ENTRIES: usize = 200_000;

/// A symbolic link in the folder `input` (a few levels down) whose target
/// lies inside `out`: an earlier output's scans, images linked from
/// elsewhere.
fn link_into(input: &Path, out: &Path) -> Option<PathBuf> {
    let out = resolved(out);
    let mut stack = vec![(input.to_path_buf(), 0usize)];
    let mut seen = 0usize;
    while let Some((dir, depth)) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for entry in entries.flatten() {
            seen += 1;
            if seen > LINK_SCAN_ENTRIES {
                return None;
            }
            let Ok(kind) = entry.file_type() else { continue };
            let path = entry.path();
            if kind.is_symlink() {
                if resolved(&path).starts_with(&out) {
                    return Some(path);
                }
            } else if kind.is_dir() && depth < LINK_SCAN_DEPTH {
                stack.push((path, depth + 1));
            }
        }
    }
    None
}

/// Checks, before a long run, that every output can be written and lies in
/// no input folder (leaving behind no file that was not there).
pub fn check_outputs(outputs: &[(&str, &Path)], inputs: &[(&str, &Path)]) -> Result<(), crate::error::Error> {
    check_outputs_apart(outputs)?;
    for (arg, path) in outputs {
        check_output(arg, path, inputs)?;
        let existed = path.exists();
        if existed && !path.is_file() {
            continue;
        }
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(|source| crate::error::Error::Io { path: path.to_path_buf(), source })?;
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

/// A test-only cap on the bytes this process writes to outputs
/// (`COSEM_TEST_WRITE_CAP`, bytes): past it a write fails as on a full
/// disk, so the out-of-space path is tested on any machine.
fn charge_write(n: usize) -> std::io::Result<()> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static CAP: std::sync::OnceLock<Option<u64>> = std::sync::OnceLock::new();
    static WRITTEN: AtomicU64 = AtomicU64::new(0);
    let cap = CAP.get_or_init(|| std::env::var("COSEM_TEST_WRITE_CAP").ok().and_then(|v| v.parse().ok()));
    if let Some(cap) = cap {
        if WRITTEN.fetch_add(n as u64, Ordering::Relaxed) + n as u64 > *cap {
            return Err(std::io::Error::from_raw_os_error(28));
        }
    }
    Ok(())
}

impl Write for Output {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        charge_write(buf.len())?;
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

/// An output folder being written: a new temporary folder beside `path`
/// ([`OutputDir::path`] is where to write), swapped into place by
/// [`OutputDir::commit`] (an existing folder is exchanged with it
/// atomically, then removed); dropped uncommitted, the temporary folder is
/// removed and `path` is untouched. Whether an existing `path` may be
/// replaced is the caller's rule, checked before.
pub struct OutputDir {
    path: PathBuf,
    tmp: Option<PathBuf>,
    /// The first of the folders made for `path`'s parent: removed again
    /// (if still empty) when the output is dropped uncommitted.
    made: Option<PathBuf>,
}

impl OutputDir {
    /// Starts writing the folder `path` (its missing parent folders are
    /// made, and removed again if it is not committed).
    pub fn create(path: &Path) -> std::io::Result<Self> {
        if std::fs::symlink_metadata(path).is_ok_and(|m| !m.is_dir()) {
            return Err(std::io::Error::new(std::io::ErrorKind::AlreadyExists, "exists and is not a folder"));
        }
        let name = match path.file_name() {
            Some(n) => n.to_string_lossy().into_owned(),
            None => return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "names no folder (ends in ..)")),
        };
        let parent = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let made = parent.ancestors().take_while(|a| !a.as_os_str().is_empty() && !a.exists()).last();
        let made = made.map(Path::to_path_buf);
        std::fs::create_dir_all(parent)?;
        let mut dir = OutputDir { path: path.to_owned(), tmp: None, made };
        static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let mut k = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        loop {
            let tmp = parent.join(format!(".{name}.cosem-{}-{k}.tmp", std::process::id()));
            match std::fs::create_dir(&tmp) {
                Ok(()) => {
                    dir.tmp = Some(tmp);
                    return Ok(dir);
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && k < u32::MAX => k += 1,
                Err(e) => return Err(e),
            }
        }
    }

    /// The temporary folder to write into.
    pub fn path(&self) -> &Path {
        self.tmp.as_deref().unwrap_or(&self.path)
    }

    /// Finishes: the folder takes `path`'s place (an existing folder there
    /// is exchanged with it in one step, then removed).
    pub fn commit(mut self) -> std::io::Result<()> {
        let Some(tmp) = self.tmp.clone() else { return Ok(()) };
        if std::fs::symlink_metadata(&self.path).is_err() {
            std::fs::rename(&tmp, &self.path)?;
            self.tmp = None;
            self.made = None;
            return Ok(());
        }
        self.made = None;
        if exchange(&tmp, &self.path).is_err() {
            // No atomic exchange on this file system: the old folder is
            // renamed aside first, and back if the new one cannot follow.
            let aside = tmp.with_extension("old");
            std::fs::rename(&self.path, &aside)?;
            if let Err(e) = std::fs::rename(&tmp, &self.path) {
                let _ = std::fs::rename(&aside, &self.path);
                return Err(e);
            }
            self.tmp = Some(aside);
        }
        // `tmp` now holds the old folder: dropped, it is removed.
        Ok(())
    }
}

impl Drop for OutputDir {
    fn drop(&mut self) {
        if let Some(tmp) = self.tmp.take() {
            let _ = std::fs::remove_dir_all(tmp);
        }
        if let Some(made) = self.made.take() {
            // The folders made for the parent, deepest first, while empty.
            let parent = self.path.parent().unwrap_or(Path::new("."));
            for dir in parent.ancestors() {
                if std::fs::remove_dir(dir).is_err() || dir == made {
                    break;
                }
            }
        }
    }
}

/// Exchanges two paths in one step (Linux's `renameat2` with
/// `RENAME_EXCHANGE`).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use std::os::unix::ffi::OsStrExt;
    let c = |p: &Path| std::ffi::CString::new(p.as_os_str().as_bytes()).map_err(std::io::Error::other);
    let (a, b) = (c(a)?, c(b)?);
    // SAFETY: two valid NUL-terminated paths, relative to the working folder.
    let r = unsafe { libc::renameat2(libc::AT_FDCWD, a.as_ptr(), libc::AT_FDCWD, b.as_ptr(), libc::RENAME_EXCHANGE) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn exchange(_: &Path, _: &Path) -> std::io::Result<()> {
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// Copies the file `from` to `to` through an [`Output`] (all or nothing).
pub fn copy_file(from: &Path, to: &Path) -> std::io::Result<()> {
    let mut out = Output::create(to)?;
    std::io::copy(&mut std::fs::File::open(from)?, &mut out)?;
    out.commit()
}

/// Writes `bytes` to `path` through an [`Output`] (all or nothing).
pub fn write_file(path: impl AsRef<Path>, bytes: impl AsRef<[u8]>) -> std::io::Result<()> {
    let mut out = Output::create(path.as_ref())?;
    out.write_all(bytes.as_ref())?;
    out.commit()
}

/// A folder removed when dropped.
pub struct TempDir(pub PathBuf);

impl TempDir {
    /// A fresh path under the system's temporary folder.
    pub fn new(prefix: &str) -> Self {
        TempDir(std::env::temp_dir().join(format!("{prefix}-{}", std::process::id())))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spellings_of_one_path_are_one() {
        let tmp = tempfile::tempdir().unwrap();
        let tmp = tmp.path();
        std::fs::create_dir_all(tmp.join("a")).unwrap();
        std::fs::write(tmp.join("a/m.cmap"), b"x").unwrap();
        let plain = tmp.join("a/m.cmap");
        let a = tmp.join("a");
        let check = |out: &Path, input: &Path| check_output("--out", out, &[("--in", input)]);
        assert_eq!(resolved(&tmp.join("a/../a/m.cmap")), resolved(&plain));
        assert_eq!(resolved(&tmp.join("a/new/deeper")), resolved(&a).join("new/deeper"));
        // A folder that does not exist yet, then `..`: the input itself.
        assert_eq!(resolved(&tmp.join("missing/../a")), resolved(&a));
        assert_eq!(resolved(&tmp.join("missing/x/../../a/m.cmap")), resolved(&plain));
        assert!(check(&tmp.join("missing/../a"), &a).is_err());
        assert!(check(&tmp.join("a/./m.cmap"), &plain).is_err());
        assert!(check(&tmp.join("a/other.ply"), &plain).is_ok());
        assert!(check(&tmp.join("a/x/../y.cmap"), &a).is_err());
        assert!(check(&tmp.join("b.cmap"), &a).is_ok());
        // An output folder that holds an input would remove it.
        let e = check(tmp, &plain).unwrap_err().to_string();
        assert!(e.contains("--out") && e.contains("--in") && e.contains("holds"), "{e}");
        // A hard link is the same file under another name.
        std::fs::hard_link(&plain, tmp.join("linked.cmap")).unwrap();
        assert!(check(&tmp.join("linked.cmap"), &plain).is_err());
        // A symbolic link, and a dangling one, to where an input is or will be.
        std::os::unix::fs::symlink(&plain, tmp.join("sym.cmap")).unwrap();
        assert!(check(&tmp.join("sym.cmap"), &plain).is_err());
        std::os::unix::fs::symlink(tmp.join("a/later"), tmp.join("dangling")).unwrap();
        assert_eq!(resolved(&tmp.join("dangling")), resolved(&a).join("later"));
        assert!(check(&tmp.join("dangling"), &a).is_err());
        // An input folder with a link into the output.
        std::fs::create_dir_all(tmp.join("out")).unwrap();
        std::fs::write(tmp.join("out/0.png"), b"x").unwrap();
        std::os::unix::fs::symlink(tmp.join("out/0.png"), tmp.join("a/0.png")).unwrap();
        let e = check(&tmp.join("out"), &a).unwrap_err().to_string();
        assert!(e.contains("a link into it"), "{e}");
        assert!(check_outputs_apart(&[("--out", &tmp.join("o")), ("--check-dir", &tmp.join("o/c"))]).is_err());
    }

    #[test]
    fn folders_are_swapped_in_whole() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("out");
        let listing = || {
            let mut v: Vec<_> = std::fs::read_dir(tmp.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
            v.sort();
            v
        };
        // Dropped uncommitted: nothing is left.
        {
            let d = OutputDir::create(&target).unwrap();
            std::fs::write(d.path().join("x"), b"1").unwrap();
        }
        assert!(listing().is_empty());
        let d = OutputDir::create(&target).unwrap();
        std::fs::write(d.path().join("x"), b"1").unwrap();
        d.commit().unwrap();
        assert_eq!(std::fs::read(target.join("x")).unwrap(), b"1");
        // Replaced: the old folder's files are gone, the new one's there.
        let d = OutputDir::create(&target).unwrap();
        std::fs::write(d.path().join("y"), b"2").unwrap();
        {
            let before = listing();
            drop(OutputDir::create(&target).unwrap());
            assert_eq!(listing().len(), before.len());
        }
        d.commit().unwrap();
        assert!(!target.join("x").exists());
        assert_eq!(std::fs::read(target.join("y")).unwrap(), b"2");
        assert_eq!(listing(), vec![std::ffi::OsString::from("out")]);
        // Missing parents are made, and removed when nothing is committed.
        drop(OutputDir::create(&tmp.path().join("missing/deeper/out")).unwrap());
        assert_eq!(listing(), vec![std::ffi::OsString::from("out")]);
        assert!(OutputDir::create(&tmp.path().join("out/..")).is_err());
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
