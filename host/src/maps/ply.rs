//! PLY export (binary little endian): x, y, z, colour, class index and the
//! SemanticKITTI id. Opens in CloudCompare, MeshLab and Open3D.

use crate::knobs::Knob;
use std::io::Write;
use std::path::Path;

/// One exported point.
#[derive(Clone, Copy, Debug)]
pub struct PlyPoint {
    /// Position (m).
    pub position: [f32; 3],
    /// Colour (RGB).
    pub color: [u8; 3],
    /// Class index (0..19), 255 for none.
    pub class: u8,
    /// Raw SemanticKITTI id.
    pub label: u16,
}

impl PlyPoint {
    /// A voxel of a map at `resolution`, moved by `t`, in `color`.
    pub fn of(
        v: &cosem_core::map::SemanticVoxel,
        resolution: f32,
        t: &cosem_core::geometry::Isometry3<f32>,
        color: [u8; 3],
    ) -> Self {
        let c = v.class();
        PlyPoint {
            position: cosem_core::geometry::transform_point(t, v.position(resolution)),
            color,
            class: c.map(|c| c.index()).unwrap_or(255),
            label: c.map(|c| c.semantic_kitti_id()).unwrap_or(0),
        }
    }
}

/// Writes points to a PLY file.
pub fn write(path: &Path, points: &[PlyPoint]) -> std::io::Result<()> {
    let mut out = Vec::with_capacity(256 + points.len() * 18);
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment cosem map export\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         property uchar class\nproperty ushort label\nend_header\n",
        points.len()
    )?;
    for p in points {
        for c in p.position {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out.extend_from_slice(&p.color);
        out.push(p.class);
        out.extend_from_slice(&p.label.to_le_bytes());
    }
    crate::paths::write_file(path, out)
}

/// `cosem export ply`: the map file `file` as a PLY point cloud coloured by
/// class (grey: no class) at `output`, never over the input. Returns the
/// points written.
pub fn export_map(file: &Path, output: &Path) -> Result<usize, crate::error::Error> {
    crate::paths::check_output(Knob::Output.name(), output, &[(Knob::File.name(), file)])?;
    let (_, map) = crate::maps::cmap::read(file)?;
    let id = cosem_core::geometry::Isometry3::identity();
    let colour = |v: &cosem_core::map::SemanticVoxel| v.class().map(|c| c.color()).unwrap_or([128; 3]);
    let points: Vec<PlyPoint> = map.iter().map(|v| PlyPoint::of(v, map.resolution(), &id, colour(v))).collect();
    write(output, &points).map_err(|e| crate::error::Error::Invalid(format!("{}: {e}", output.display())))?;
    Ok(points.len())
}

/// `cosem match --merged`: the model (blue) and the scene moved onto it by
/// `t_model_scene` (orange) in one PLY file.
pub fn write_merged(
    path: &Path,
    model: &crate::maps::mapping::HostMap,
    scene: &crate::maps::mapping::HostMap,
    t_model_scene: &cosem_core::geometry::Isometry3<f32>,
) -> Result<(), crate::error::Error> {
    let id = cosem_core::geometry::Isometry3::identity();
    let mut pts: Vec<PlyPoint> = Vec::with_capacity(model.len() + scene.len());
    pts.extend(model.iter().map(|v| PlyPoint::of(v, model.resolution(), &id, [40, 110, 255])));
    pts.extend(scene.iter().map(|v| PlyPoint::of(v, scene.resolution(), t_model_scene, [255, 120, 30])));
    write(path, &pts).map_err(|e| crate::error::Error::Invalid(format!("{}: {e}", path.display())))
}
