//! A match as a ROS 2 recording to view in Foxglove: both maps as
//! PointCloud2 coloured by class, the found transform on `/tf`, the result
//! as JSON text.

use crate::maps::mapping::HostMap;
use crate::reports::report::MatchJson;
use crate::sources::recording::{transform_of, RecordingWriter};
use crate::sources::ros_msgs::*;
use nalgebra::Isometry3;
use std::path::Path;

/// A map's voxels as a PointCloud2 in `frame`: x, y, z (float32), rgba
/// (uint32: the class's colour, opaque), label (uint32: the SemanticKITTI
/// id of the voxel's class, 0 without one), class (uint8: its index, 255
/// without one).
pub(crate) fn map_cloud(map: &HostMap, frame: &str) -> PointCloud2 {
    let step = 21u32;
    let mut data = Vec::with_capacity(map.len() * step as usize);
    for v in map.iter() {
        for c in v.position(map.resolution()) {
            data.extend_from_slice(&c.to_le_bytes());
        }
        let class = v.class();
        let [r, g, b] = class.map(|c| c.color()).unwrap_or([128; 3]);
        data.extend_from_slice(&u32::from_be_bytes([r, g, b, 255]).to_le_bytes());
        data.extend_from_slice(&u32::from(class.map_or(0, |c| c.semantic_kitti_id())).to_le_bytes());
        data.push(class.map_or(255, |c| c.index()));
    }
    let field = |name: &str, offset, datatype| PointField { name: name.into(), offset, datatype, count: 1 };
    PointCloud2 {
        header: Header { stamp: Time::default(), frame_id: frame.into() },
        height: 1,
        width: map.len() as u32,
        fields: vec![
            field("x", 0, 7),
            field("y", 4, 7),
            field("z", 8, 7),
            field("rgba", 12, 6),
            field("label", 16, 6),
            field("class", 20, 2),
        ],
        is_bigendian: false,
        point_step: step,
        row_step: step * map.len() as u32,
        data,
        is_dense: true,
    }
}

/// Writes a match to view in Foxglove: both maps as PointCloud2 coloured
/// by class (`/cosem/model` in frame `model`, `/cosem/scene` in frame
/// `scene`), the found `T_model_scene` on `/tf` (`model -> scene`) and the
/// result (`cosem match --json`'s) as JSON text on `/cosem/status` (`std_msgs/msg/String`).
pub fn write_match(
    path: &Path,
    model: &HostMap,
    scene: &HostMap,
    t_model_scene: &Isometry3<f32>,
    status: &MatchJson,
) -> Result<(), crate::error::Error> {
    let status_json =
        serde_json::to_string(status).map_err(|e| crate::error::Error::Invalid(format!("{}: {e}", path.display())))?;
    let mut w = RecordingWriter::create(path)?;
    let pc = w.schema("sensor_msgs/msg/PointCloud2", POINTCLOUD2_SCHEMA)?;
    let tf = w.schema("tf2_msgs/msg/TFMessage", TFMESSAGE_SCHEMA)?;
    let st = w.schema("std_msgs/msg/String", STRING_SCHEMA)?;
    let (model_ch, scene_ch) = (w.channel(pc, "/cosem/model")?, w.channel(pc, "/cosem/scene")?);
    let (tf_ch, status_ch) = (w.channel(tf, "/tf")?, w.channel(st, "/cosem/status")?);
    let t: Isometry3<f64> = nalgebra::convert(*t_model_scene);
    let tf_msg = TfMessage {
        transforms: vec![TransformStamped {
            header: Header { stamp: Time::default(), frame_id: "model".into() },
            child_frame_id: "scene".into(),
            transform: transform_of(&t.to_homogeneous()),
        }],
    };
    w.write(model_ch, 0, 0, &map_cloud(model, "model"))?;
    w.write(scene_ch, 0, 0, &map_cloud(scene, "scene"))?;
    w.write(tf_ch, 0, 0, &tf_msg)?;
    w.write(status_ch, 0, 0, &StringMsg { data: status_json })?;
    w.finish()
}
