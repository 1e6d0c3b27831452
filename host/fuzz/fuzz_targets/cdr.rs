//! Any bytes as a ROS 2 message (PointCloud2, TFMessage, Odometry): no
//! panic, and a cloud's data borrowed from the input.
#![no_main]

use cosem_host::cdr_read::Cdr;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(pc) = Cdr::new(data).and_then(|mut c| c.point_cloud()) {
        assert!(pc.data.len() <= data.len());
    }
    let _ = Cdr::new(data).and_then(|mut c| c.tf_message());
    let _ = Cdr::new(data).and_then(|mut c| c.odometry_pose());
});
