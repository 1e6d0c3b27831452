//! Seeded property tests of every reader of users' files: valid files
//! mutated thousands of times (bit flips, bytes set, extreme lengths and
//! counts written over fields, bytes inserted and deleted, files cut
//! short; in text, numbers replaced by extreme ones) must give a result or
//! a typed error: never a panic, never a hang, and no allocation larger
//! than the file's size allows. A recording whose chunks carry CRCs that
//! still reads must give exactly the original scans (a corruption is never
//! silently read). Each target runs a fixed number of cases or until its
//! time cap, whichever comes first; the seed and the case are printed on a
//! failure. `cargo fuzz` targets of the same readers are in `host/fuzz`.
//! Images (segmentation PNGs, camera PNGs, `.npy` probability maps) are
//! mutated the same way, and PNG chunks get their CRCs recomputed after a
//! mutation half of the time, so that the decoder's header and size checks
//! are reached and not only its checksum.

use cosem_host::camera::seg_files::{
    npy_bytes, read_probabilities, read_rgb_png, read_seg_png, write_rgb_png, write_seg_png, RgbImage, SegImage,
};
use cosem_host::sources::class_table::ClassTable;
use cosem_host::sources::cloud::{read_pcd, read_ply, read_poses, write_pcd, write_ply, write_poses};
use cosem_host::sources::kitti::FrameRange;
use cosem_host::sources::recording::{read_scans, write_scans, ChunkCompression, RecordingScans, ScanRecord};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;
use std::time::{Duration, Instant};

/// The largest single allocation of this thread since the last reset.
struct Counting;

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// Cases per target, and the time cap of each.
const CASES: usize = 10_000;
const TIME_CAP: Duration = Duration::from_secs(12);

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        // splitmix64
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// One to three byte-level mutations of `bytes`.
fn mutate(bytes: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut b = bytes.to_vec();
    for _ in 0..1 + rng.below(3) {
        if b.is_empty() {
            b.push(rng.next() as u8);
            continue;
        }
        let at = rng.below(b.len());
        match rng.below(7) {
            0 => b[at] ^= 1 << rng.below(8),
            1 => b[at] = rng.next() as u8,
            2 => {
                let extreme =
                    [0u32, u32::MAX, 0xFFFF_FFF0, 0x7FFF_FFFF, 0x8000_0000, b.len() as u32, rng.next() as u32];
                let v = extreme[rng.below(extreme.len())].to_le_bytes();
                let n = v.len().min(b.len() - at);
                b[at..at + n].copy_from_slice(&v[..n]);
            }
            3 => {
                let extreme = [u64::MAX, 1 << 40, 1 << 32, 0, b.len() as u64 * 4, rng.next()];
                let v = extreme[rng.below(extreme.len())].to_le_bytes();
                let n = v.len().min(b.len() - at);
                b[at..at + n].copy_from_slice(&v[..n]);
            }
            4 => {
                b.remove(at);
            }
            5 => b.insert(at, rng.next() as u8),
            _ => b.truncate(at),
        }
    }
    b
}

/// In text, one number replaced by an extreme one (or a byte mutation).
fn mutate_text(bytes: &[u8], rng: &mut Rng) -> Vec<u8> {
    if rng.below(3) == 0 {
        return mutate(bytes, rng);
    }
    let digits: Vec<usize> = (0..bytes.len()).filter(|&i| bytes[i].is_ascii_digit()).collect();
    if digits.is_empty() {
        return mutate(bytes, rng);
    }
    let start = digits[rng.below(digits.len())];
    let end = (start..bytes.len()).find(|&i| !bytes[i].is_ascii_digit()).unwrap_or(bytes.len());
    let extreme = [
        "18446744073709551608",
        "18446744073709551616",
        "4294967296",
        "4294967295",
        "-1",
        "0",
        "nan",
        "inf",
        "1e300",
        "99999999999999999999999",
        "",
    ];
    let mut b = bytes[..start].to_vec();
    b.extend_from_slice(extreme[rng.below(extreme.len())].as_bytes());
    b.extend_from_slice(&bytes[end..]);
    b
}

/// Runs `read` on mutations of `valid` (written to a file in `dir`):
/// no panic, and no allocation beyond `limit(len)` for a file of `len`
/// bytes. `read` returns whether the input was accepted.
fn fuzz(
    name: &str,
    seed: u64,
    valid: &[u8],
    mutator: fn(&[u8], &mut Rng) -> Vec<u8>,
    dir: &Path,
    limit: impl Fn(usize) -> usize,
    mut read: impl FnMut(&Path, &[u8]) -> bool,
) -> (usize, usize) {
    let path = dir.join(name);
    let mut rng = Rng(seed);
    let started = Instant::now();
    let (mut cases, mut accepted) = (0, 0);
    while cases < CASES && started.elapsed() < TIME_CAP {
        let bytes = mutator(valid, &mut rng);
        std::fs::write(&path, &bytes).unwrap();
        LARGEST.with(|l| l.set(0));
        let ok = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| read(&path, &bytes)));
        let largest = LARGEST.with(Cell::get);
        let keep = dir.join(format!("{name}.case{cases}"));
        match ok {
            Err(_) => {
                std::fs::copy(&path, &keep).unwrap();
                panic!("{name}: seed {seed} case {cases}: the reader panicked (input kept at {})", keep.display());
            }
            Ok(a) => accepted += usize::from(a),
        }
        if largest > limit(bytes.len()) {
            std::fs::copy(&path, &keep).unwrap();
            panic!(
                "{name}: seed {seed} case {cases}: an allocation of {largest} bytes for a file of {} (input kept at {})",
                bytes.len(),
                keep.display()
            );
        }
        cases += 1;
    }
    println!(
        "{name}: {cases} mutated files in {:.1} s, {accepted} read, the rest refused with an error",
        started.elapsed().as_secs_f64()
    );
    assert!(cases >= 200, "{name}: only {cases} cases within the time cap");
    (cases, accepted)
}

/// A scan: points, label words, the sensor's pose.
type Scan = (Vec<[f32; 3]>, Vec<u32>, nalgebra::Matrix4<f64>);

/// Small labelled scans with poses along a curve.
fn scans() -> Vec<Scan> {
    let mut rng = Rng(7);
    (0..3)
        .map(|k| {
            let points: Vec<[f32; 3]> = (0..150)
                .map(|_| {
                    let f = |r: &mut Rng| (r.below(20_000) as f32 - 10_000.0) * 1e-3;
                    [f(&mut rng), f(&mut rng), f(&mut rng) * 0.2]
                })
                .collect();
            let labels = (0..150).map(|i| [40u32, 50, 70, 0x0002_000A][i % 4]).collect();
            let yaw = 0.1 * k as f64;
            let pose = nalgebra::Isometry3::new(
                nalgebra::Vector3::new(k as f64, 0.5 * k as f64, 0.0),
                nalgebra::Vector3::z() * yaw,
            )
            .to_homogeneous();
            (points, labels, pose)
        })
        .collect()
}

fn recording(path: &Path, compression: ChunkCompression, crcs: bool) -> Vec<u8> {
    let s = scans();
    let records = s.iter().enumerate().map(|(k, (points, labels, pose))| ScanRecord {
        points,
        labels,
        pose: *pose,
        seconds: 0.1 * k as f64,
    });
    write_scans(path, "/points", compression, crcs, records).unwrap();
    std::fs::read(path).unwrap()
}

fn what(frames: Option<FrameRange>) -> RecordingScans<'static> {
    RecordingScans { points: "/points", label_field: "label", pose_frame: "world", frames, odom: None, strict: true }
}

#[test]
fn mutated_recordings_never_panic_and_checksummed_ones_never_read_wrong() {
    let tmp = tempfile::tempdir().unwrap();
    for (k, (compression, crcs)) in
        [(ChunkCompression::None, false), (ChunkCompression::Zstd, true), (ChunkCompression::Lz4, true)]
            .into_iter()
            .enumerate()
    {
        let valid = recording(&tmp.path().join(format!("valid{k}.mcap")), compression, crcs);
        let frames = Some(FrameRange { start: 0, end: 3, stride: 1 });
        let (want, _) = read_scans(&tmp.path().join(format!("valid{k}.mcap")), &what(frames)).unwrap();
        assert_eq!(want.len(), 3);
        let name = format!("{compression:?}.mcap");
        // A chunk's records are held decompressed: the declared size grows
        // them at most to what the decoder produced (and read_to_end doubles).
        let limit = |len: usize| 1 << 20 | (64 * len);
        fuzz(&name, 11 + k as u64, &valid, mutate, tmp.path(), limit, |p, _| {
            let got = read_scans(p, &what(frames));
            if crcs {
                if let Ok((f, _)) = &got {
                    let same = f.len() == want.len()
                        && f.iter()
                            .zip(&want)
                            .all(|(a, b)| a.points == b.points && a.labels == b.labels && a.pose == b.pose);
                    assert!(same, "a corrupted recording with chunk CRCs was read as different scans");
                }
            }
            got.is_ok()
        });
    }
}

#[test]
fn mutated_pcd_and_ply_files_never_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let (points, labels, _) = scans().remove(0);
    let limit = |len: usize| (1 << 16) + 8 * len;
    for (k, ext) in ["pcd", "ply"].into_iter().enumerate() {
        let p = tmp.path().join(format!("valid.{ext}"));
        if ext == "pcd" {
            write_pcd(&p, &points, &labels).unwrap();
        } else {
            write_ply(&p, &points, &labels).unwrap();
        }
        let valid = std::fs::read(&p).unwrap();
        let read =
            |p: &Path, _: &[u8]| if ext == "pcd" { read_pcd(p, "label").is_ok() } else { read_ply(p, "label").is_ok() };
        fuzz(&format!("binary.{ext}"), 21 + k as u64, &valid, mutate, tmp.path(), limit, read);
        // The header's numbers (COUNT, WIDTH, HEIGHT, POINTS, element counts).
        fuzz(&format!("header.{ext}"), 31 + k as u64, &valid, mutate_text, tmp.path(), limit, read);
    }
    let ascii = "VERSION 0.7\nFIELDS x y z label\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 3\nHEIGHT 1\n\
                 VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n1 2 3 40\n4 5 6 50\n7 8 9 70\n";
    fuzz("ascii.pcd", 41, ascii.as_bytes(), mutate_text, tmp.path(), limit, |p, _| read_pcd(p, "label").is_ok());
    let ply = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
               property uint label\nend_header\n1 2 3 40\n4 5 6 50\n";
    fuzz("ascii.ply", 42, ply.as_bytes(), mutate_text, tmp.path(), limit, |p, _| read_ply(p, "label").is_ok());
}

#[test]
fn mutated_poses_and_class_tables_never_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("poses.txt");
    write_poses(&p, &scans().iter().map(|s| s.2).collect::<Vec<_>>()).unwrap();
    let valid = std::fs::read(&p).unwrap();
    let limit = |len: usize| (1 << 16) + 8 * len;
    fuzz("poses.txt", 51, &valid, mutate_text, tmp.path(), limit, |p, _| read_poses(p).is_ok());
    let table = "# ids\n[ids]\n0 = \"unlabeled\"\n1 = \"road\"\n2 = \"sidewalk\"\n7 = \"car\"\n40 = \"building\"\n";
    fuzz("classes.toml", 52, table.as_bytes(), mutate_text, tmp.path(), limit, |_, b| {
        std::str::from_utf8(b).is_ok_and(|t| ClassTable::parse(t).is_ok())
    });
}

/// `png` with every whole chunk's CRC recomputed (a mutated file that the
/// decoder then reads past its checksums).
fn fix_png_crcs(mut png: Vec<u8>) -> Vec<u8> {
    let mut at = 8;
    while at + 12 <= png.len() {
        let len = u32::from_be_bytes([png[at], png[at + 1], png[at + 2], png[at + 3]]) as usize;
        let Some(end) = (at + 8).checked_add(len).filter(|e| e + 4 <= png.len()) else { break };
        let crc = cosem_core::wire::crc::crc32(&png[at + 4..end]).to_be_bytes();
        png[end..end + 4].copy_from_slice(&crc);
        at = end + 4;
    }
    png
}

/// A PNG mutation: bytes as [`mutate`], or the header's width and height
/// set to extreme values; half of the time with the CRCs made right again.
fn mutate_png(valid: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut b = if rng.below(3) == 0 && valid.len() > 24 {
        let mut b = valid.to_vec();
        let sizes = [0u32, 1, 0x7FFF_FFFF, u32::MAX, 65_536, 200_000, 1 << 20, rng.next() as u32 % 100_000];
        let at = 16 + 4 * rng.below(2);
        b[at..at + 4].copy_from_slice(&sizes[rng.below(sizes.len())].to_be_bytes());
        b
    } else {
        mutate(valid, rng)
    };
    if rng.below(2) == 0 {
        b = fix_png_crcs(b);
    }
    b
}

/// A small image with structure (blocks of ids) and some noise.
fn ids(width: u32, height: u32, rng: &mut Rng) -> Vec<u8> {
    (0..width * height)
        .map(|i| if rng.below(10) == 0 { rng.next() as u8 } else { ((i % width) / 7 + 3 * (i / width / 5)) as u8 })
        .collect()
}

#[test]
fn mutated_images_and_probability_maps_never_panic_nor_allocate_beyond_their_size() {
    let tmp = tempfile::tempdir().unwrap();
    let mut rng = Rng(61);
    let (w, h) = (48u32, 20u32);
    // A PNG's pixels are bounded by 1032x its bytes (deflate's ratio) and
    // the decoder holds at most 4 bytes a pixel (RGBA, 16-bit stripped),
    // plus its inflater's window and tables.
    let png_limit = |len: usize| (1 << 20) + 4 * 1032 * len;
    let seg = tmp.path().join("seg.png");
    write_seg_png(&seg, &SegImage { width: w, height: h, ids: ids(w, h, &mut rng) }).unwrap();
    let valid = std::fs::read(&seg).unwrap();
    let want = read_seg_png(&seg).unwrap();
    // Some mutations read, most are refused: the mutations reach both.
    let png_fuzz = |name: &str, seed: u64, valid: &[u8], read: &dyn Fn(&Path) -> bool| {
        let (cases, accepted) = fuzz(name, seed, valid, mutate_png, tmp.path(), png_limit, |p, _| read(p));
        assert!(accepted > 0 && accepted < cases, "{name}: {accepted} of {cases} read: the mutations missed");
    };
    png_fuzz("mutated-seg.png", 62, &valid, &|p| {
        let got = read_seg_png(p);
        if let Ok(img) = &got {
            assert_eq!(img.ids.len(), img.width as usize * img.height as usize, "ids for every pixel");
        }
        got.is_ok()
    });
    // A camera image, RGB and grey (expanded to RGB on reading).
    let rgb: Vec<u8> = ids(w, h, &mut rng).iter().flat_map(|&v| [v, v.wrapping_mul(3), 255 - v]).collect();
    let cam = tmp.path().join("cam.png");
    let image = RgbImage { width: w, height: h, rgb };
    write_rgb_png(&cam, &image).unwrap();
    assert_eq!(read_rgb_png(&cam).unwrap(), image);
    let read_rgb = |p: &Path| {
        let got = read_rgb_png(p);
        if let Ok(img) = &got {
            assert_eq!(img.rgb.len(), 3 * img.width as usize * img.height as usize, "RGB for every pixel");
        }
        got.is_ok()
    };
    png_fuzz("mutated-cam.png", 63, &std::fs::read(&cam).unwrap(), &read_rgb);
    png_fuzz("grey.png", 64, &valid, &read_rgb);
    // The right file read right, after all of that.
    assert_eq!(read_seg_png(&seg).unwrap(), want);

    // Probability maps: the whole file is read (its size), the values at
    // most 4 bytes per data byte, and an (H, W, C) copy of a (C, H, W) map.
    let npy_limit = |len: usize| (1 << 16) + 8 * len;
    let channels = 4;
    let f4: Vec<u8> = (0..w * h * channels as u32).flat_map(|i| ((i % 7) as f32 / 7.0).to_le_bytes()).collect();
    let hwc = npy_bytes("<f4", &[h as usize, w as usize, channels], &f4);
    fuzz("hwc.npy", 65, &hwc, mutate, tmp.path(), npy_limit, |p, _| read_probabilities(p, channels).is_ok());
    let u1: Vec<u8> = (0..w * h * channels as u32).map(|i| (i % 251) as u8).collect();
    let chw = npy_bytes("|u1", &[channels, h as usize, w as usize], &u1);
    fuzz("chw.npy", 66, &chw, mutate, tmp.path(), npy_limit, |p, _| read_probabilities(p, channels).is_ok());
    // The header's numbers (its version, header length and shape).
    fuzz("shape.npy", 67, &chw, mutate_text, tmp.path(), npy_limit, |p, _| read_probabilities(p, channels).is_ok());
}
