//! Which camera a segmentation image belongs to: its size checked against
//! the camera's own images (or `--image-size`, or the calibration's
//! principal point), its ids against the class set, and the projection
//! scaled to it when asked.

use super::*;

/// `WIDTHxHEIGHT` of an image (`--image-size`), both positive.
pub fn parse_image_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("{} `{s}`: expected WIDTHxHEIGHT, e.g. 1241x376", Knob::ImageSize);
    let (w, h) = s.split_once('x').ok_or_else(bad)?;
    let (w, h) = (w.parse::<u32>().map_err(|_| bad())?, h.parse::<u32>().map_err(|_| bad())?);
    if w == 0 || h == 0 {
        return Err(bad());
    }
    Ok((w, h))
}

/// Checks every pixel of an image holds an id of the class set.
pub(super) fn check_ids(path: &Path, image: &SegImage, classes: SegClasses) -> Result<(), LabelError> {
    for (i, &id) in image.ids.iter().enumerate() {
        if classes.class(id).is_err() {
            let w = image.width.max(1) as usize;
            return Err(LabelError::UnknownClass {
                path: path.to_path_buf(),
                u: (i % w) as u32,
                v: (i / w) as u32,
                id,
                classes: classes.name(),
            });
        }
    }
    Ok(())
}

pub(super) fn check_size(path: &Path, got: (u32, u32), want: (u32, u32)) -> Result<(), LabelError> {
    if got != want {
        return Err(LabelError::ImageSize {
            path: path.to_path_buf(),
            got_w: got.0,
            got_h: got.1,
            want_w: want.0,
            want_h: want.1,
        });
    }
    Ok(())
}

/// The size of a PNG image, from its header.
pub(super) fn png_size(path: &Path) -> Option<(u32, u32)> {
    use std::io::Read;
    let mut head = [0u8; 24];
    std::fs::File::open(path).ok()?.read_exact(&mut head).ok()?;
    let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    (&head[..8] == b"\x89PNG\r\n\x1a\n" && &head[12..16] == b"IHDR").then(|| (be(&head[16..20]), be(&head[20..24])))
}

/// The camera for segmentation images of `size`: the camera's own image
/// size is `--image-size`, else its images' (`image_<camera>/` beside the
/// scans), else where the principal point lies (about twice it). Images of
/// another size are refused, naming both, unless `scale_to_images` asks to
/// scale the projection to them (returned: the size scaled from).
pub(super) fn camera_for(
    o: &LabelOptions,
    seq: &Sequence,
    size: (u32, u32),
    image: &Path,
    frame: usize,
) -> Result<(Camera, Option<(u32, u32)>), LabelError> {
    let own = o.image_size.map(|s| (s, Knob::ImageSize.name())).or_else(|| {
        png_size(&seq.dir.join(format!("image_{}/{frame:06}.png", o.camera))).map(|s| (s, "the camera's image"))
    });
    let mismatch = |camera: (u32, u32), from: &str| {
        LabelError::Format {
        path: image.to_path_buf(),
        what: format!(
            "segmentation of {}x{} pixels, but camera {}'s images are {}x{} ({from}): give segmentation at the camera's size, \
             or {} to scale the projection to it{}",
            size.0,
            size.1,
            o.camera,
            camera.0,
            camera.1,
            Knob::ScaleToImages,
            if from.starts_with("about") { format!(" (with {} WxH of the camera's images)", Knob::ImageSize) } else { String::new() }
        ),
    }
    };
    match own {
        Some((own, _)) if own == size => Ok((camera_of(seq, o.camera, size, image)?, None)),
        Some((own, _)) if o.scale_to_images => {
            let cam = scaled_camera(seq, o.camera, own, size, image)?;
            Ok((cam, Some(own)))
        }
        Some((own, from)) => Err(mismatch(own, from)),
        None => {
            // No size to go by but the calibration: the principal point lies
            // near the image's centre (KITTI: within 3%).
            let p = seq.projection(o.camera)?;
            let (cx, cy) = (p[(0, 2)], p[(1, 2)]);
            let near = |c: f64, n: u32| (2.0 * c - f64::from(n)).abs() <= 0.1 * f64::from(n);
            if near(cx, size.0) && near(cy, size.1) {
                Ok((camera_of(seq, o.camera, size, image)?, None))
            } else {
                let about = ((2.0 * cx).round().max(0.0) as u32, (2.0 * cy).round().max(0.0) as u32);
                Err(mismatch(about, &format!("about twice its principal point ({cx:.1}, {cy:.1}) in calib.txt")))
            }
        }
    }
}

/// The camera of `seq` with its projection scaled from images of `from`
/// pixels to images of `to` pixels (pixel centres kept).
pub(super) fn scaled_camera(
    seq: &Sequence,
    camera: u8,
    from: (u32, u32),
    to: (u32, u32),
    image: &Path,
) -> Result<Camera, LabelError> {
    let p = seq.projection(camera)?;
    let (sx, sy) = (f64::from(to.0) / f64::from(from.0), f64::from(to.1) / f64::from(from.1));
    let mut q = p;
    for c in 0..4 {
        // u' = (u + 0.5) sx - 0.5, in homogeneous rows.
        q[(0, c)] = p[(0, c)] * sx + (0.5 * sx - 0.5) * p[(2, c)];
        q[(1, c)] = p[(1, c)] * sy + (0.5 * sy - 0.5) * p[(2, c)];
    }
    camera_from(seq, camera, &q, to, image)
}

/// The camera of `seq` for images of `size`: `P<camera>` after `Tr`. The
/// principal point must lie in the image (else the image is not this
/// camera's, or the size is wrong).
pub fn camera_of(seq: &Sequence, camera: u8, size: (u32, u32), image: &Path) -> Result<Camera, LabelError> {
    camera_from(seq, camera, &seq.projection(camera)?, size, image)
}

pub(super) fn camera_from(
    seq: &Sequence,
    camera: u8,
    p: &nalgebra::Matrix4<f64>,
    size: (u32, u32),
    image: &Path,
) -> Result<Camera, LabelError> {
    let p = *p;
    let rows = |m: &nalgebra::Matrix4<f64>| -> [f32; 12] {
        let mut out = [0.0f32; 12];
        for r in 0..3 {
            for c in 0..4 {
                out[r * 4 + c] = m[(r, c)] as f32;
            }
        }
        out
    };
    let calib = seq.dir.join("calib.txt");
    let cam = Camera::new(&rows(&p), &rows(seq.tr_matrix()), size.0, size.1).map_err(|e| LabelError::Camera {
        path: calib.clone(),
        camera,
        what: e.to_string(),
    })?;
    let (cx, cy) = (p[(0, 2)], p[(1, 2)]);
    if !(cx >= 0.0 && cy >= 0.0 && cx < f64::from(size.0) && cy < f64::from(size.1)) {
        return Err(LabelError::Format {
            path: image.to_path_buf(),
            what: format!(
                "image size {}x{} does not contain camera {camera}'s principal point ({cx:.1}, {cy:.1}) from {}",
                size.0,
                size.1,
                calib.display()
            ),
        });
    }
    Ok(cam)
}
