//! Any bytes as a segmentation PNG, a camera PNG and a `.npy` probability
//! map: no panic, and what is read has exactly its stated pixels. (The
//! readers take paths: each input is written to one scratch file.)
#![no_main]

use cosem_host::seg_files::{read_probabilities, read_rgb_png, read_seg_png};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = std::env::temp_dir().join(format!("cosem-fuzz-image-{}", std::process::id()));
    std::fs::write(&path, data).unwrap();
    if let Ok(img) = read_seg_png(&path) {
        assert_eq!(img.ids.len(), img.width as usize * img.height as usize);
    }
    if let Ok(img) = read_rgb_png(&path) {
        assert_eq!(img.rgb.len(), 3 * img.width as usize * img.height as usize);
    }
    if let Ok(p) = read_probabilities(&path, 19) {
        assert_eq!(p.values.len(), 19 * p.width as usize * p.height as usize);
        assert!(p.values.len() <= data.len());
    }
});
