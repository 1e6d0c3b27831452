//! Bounds on the numbers that size work, checked before anything is
//! allocated or started: threads, and the pixels of an image or of a
//! network's input. A number from a user or a file never sizes an
//! allocation unchecked.

use crate::knobs::Knob;
use std::sync::atomic::{AtomicU64, Ordering};

/// The machine's cores (1 when unknown).
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Threads at most: four times the machine's cores.
pub fn max_threads() -> usize {
    4 * cores()
}

/// Checks a thread count given as `arg`: at least 1, at most
/// [`max_threads`].
pub fn threads(arg: &str, n: usize) -> Result<usize, String> {
    let max = max_threads();
    match n {
        0 => Err(format!("{arg} 0: expected at least 1 thread")),
        n if n > max => Err(format!("{arg} {n}: at most {max} threads (4 x this machine's {} cores)", cores())),
        n => Ok(n),
    }
}

/// Deflate's largest ratio: a PNG of `b` bytes holds at most about
/// `1032 b` bytes of pixels.
pub const DEFLATE_RATIO: u64 = 1032;

/// The default cap on an image's pixels (or a network's input's): 2^26,
/// 67 megapixels (8192 x 8192). The option `--max-pixels` raises it.
pub const DEFAULT_MAX_PIXELS: u64 = 1 << 26;

static MAX_PIXELS: AtomicU64 = AtomicU64::new(DEFAULT_MAX_PIXELS);

/// The cap on an image's pixels in force.
pub fn max_pixels() -> u64 {
    MAX_PIXELS.load(Ordering::Relaxed)
}

/// Sets the cap on an image's pixels (`--max-pixels`): at least 1.
pub fn set_max_pixels(n: u64) {
    MAX_PIXELS.store(n.max(1), Ordering::Relaxed);
}

/// Checks an image's stated size against the cap and against what its
/// file can hold (`file_bytes` compressed, at most [`DEFLATE_RATIO`] x
/// as many pixels): a header's claim never sizes an allocation alone.
pub fn image_pixels(width: u32, height: u32, file_bytes: u64) -> Result<u64, String> {
    let pixels = u64::from(width) * u64::from(height);
    if pixels == 0 {
        return Err(format!("the header says {width}x{height}: an image with no pixels"));
    }
    let cap = max_pixels();
    if pixels > cap {
        return Err(format!(
            "the header says {width}x{height} = {pixels} pixels, above the cap of {cap} (raise it with {})",
            Knob::MaxPixels
        ));
    }
    let holds = file_bytes.saturating_mul(DEFLATE_RATIO);
    if pixels > holds {
        return Err(format!(
            "the header says {width}x{height} = {pixels} pixels, more than a file of {file_bytes} bytes can hold \
             (at most {holds} at deflate's largest ratio): a corrupt or forged header"
        ));
    }
    Ok(pixels)
}

/// Checks a network's input size (`height` x `width`) against the cap.
pub fn network_pixels(height: usize, width: usize) -> Result<u64, String> {
    let pixels = (height as u64).saturating_mul(width as u64);
    let cap = max_pixels();
    if pixels == 0 || pixels > cap {
        return Err(format!(
            "input {height}x{width} = {pixels} pixels: expected 1 to {cap} (the cap; raise it with {})",
            Knob::MaxPixels
        ));
    }
    Ok(pixels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn images_are_bounded_by_their_files_and_the_cap() {
        assert!(image_pixels(1242, 375, 20_000).is_ok());
        // A 68-byte file cannot hold 200000 x 200000 pixels.
        let e = image_pixels(200_000, 200_000, 68).unwrap_err();
        assert!(e.contains("200000x200000") && e.contains("max_pixels"), "{e}");
        assert!(image_pixels(10_000, 10_000, 1 << 30).unwrap_err().contains("cap"));
        assert!(image_pixels(100, 100, 5).unwrap_err().contains("5 bytes"));
        assert!(image_pixels(0, 7, 100).is_err());
        assert!(network_pixels(65_536, 65_536).is_err());
        assert!(network_pixels(512, 1024).is_ok());
        assert!(threads("--threads", max_threads() + 1).unwrap_err().contains("--threads"));
        assert!(threads("--threads", 0).is_err());
        assert_eq!(threads("--threads", 1), Ok(1));
    }
}
