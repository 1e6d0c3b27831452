//! Decoding the ROS 2 messages a recording's scans and poses come in
//! (CDR, little or big endian as its encapsulation header says): every
//! string and sequence length is checked against the bytes left in the
//! message before anything is allocated, and a point cloud's bytes are
//! borrowed, not copied. Errors name the byte offset in the message.

use crate::sources::ros_msgs::{Header, Quaternion, Time, Transform, TransformStamped, Vector3};

/// A CDR cursor: offsets (and alignment) count from after the 4-byte
/// encapsulation header.
pub struct Cdr<'a> {
    b: &'a [u8],
    pos: usize,
    little: bool,
}

/// A `sensor_msgs/msg/PointCloud2` whose data borrows the message.
#[derive(Clone, Debug, PartialEq)]
pub struct CloudMsg<'a> {
    /// Stamp and frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Points a row.
    pub width: u32,
    /// name, offset, datatype, count.
    pub fields: Vec<(String, u32, u8, u32)>,
    /// Big-endian data.
    pub is_bigendian: bool,
    /// Bytes a point.
    pub point_step: u32,
    /// Bytes a row.
    pub row_step: u32,
    /// The points' bytes.
    pub data: &'a [u8],
}

impl<'a> Cdr<'a> {
    /// A message's payload after its encapsulation header (`CDR_BE` 0x0000
    /// or `CDR_LE` 0x0001; the options are ignored).
    pub fn new(message: &'a [u8]) -> Result<Self, String> {
        match message {
            [0, kind @ (0 | 1), _, _, rest @ ..] => Ok(Cdr { b: rest, pos: 0, little: *kind == 1 }),
            [a, b, ..] => Err(format!("encapsulation 0x{a:02x}{b:02x} is not plain CDR (0x0000 or 0x0001)")),
            _ => Err(format!("{} bytes, too short for a CDR message", message.len())),
        }
    }

    fn err(&self, what: impl std::fmt::Display) -> String {
        format!("byte {} of the message: {what}", self.pos + 4)
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        let left = self.b.len() - self.pos;
        if n > left {
            return Err(self.err(format!("{what} needs {n} bytes, the message has {left} left")));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn align(&mut self, n: usize) -> Result<(), String> {
        let pad = (n - self.pos % n) % n;
        self.take(pad, "padding").map(|_| ())
    }

    fn fixed<const N: usize>(&mut self, what: &str) -> Result<[u8; N], String> {
        self.align(N)?;
        let mut out = [0u8; N];
        out.copy_from_slice(self.take(N, what)?);
        if !self.little {
            out.reverse();
        }
        Ok(out)
    }

    fn u8(&mut self, what: &str) -> Result<u8, String> {
        Ok(self.take(1, what)?[0])
    }

    fn bool(&mut self, what: &str) -> Result<bool, String> {
        match self.u8(what)? {
            0 => Ok(false),
            1 => Ok(true),
            v => Err(self.err(format!("{what} is {v}, not a bool"))),
        }
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        self.fixed::<4>(what).map(u32::from_le_bytes)
    }

    fn i32(&mut self, what: &str) -> Result<i32, String> {
        self.fixed::<4>(what).map(i32::from_le_bytes)
    }

    fn f64(&mut self, what: &str) -> Result<f64, String> {
        self.fixed::<8>(what).map(f64::from_le_bytes)
    }

    /// A sequence's length, checked against what is left at `min` bytes an
    /// element.
    fn len(&mut self, what: &str, min: usize) -> Result<usize, String> {
        self.align(4)?;
        let at = self.pos + 4;
        let n = self.u32(what)? as usize;
        let left = self.b.len() - self.pos;
        if n.saturating_mul(min) > left {
            return Err(format!(
                "byte {at} of the message: {what}: a length of {n} announced, the message has {left} bytes left"
            ));
        }
        Ok(n)
    }

    fn string(&mut self, what: &str) -> Result<String, String> {
        let n = self.len(what, 1)?;
        let b = self.take(n, what)?;
        // The length counts the terminating NUL.
        let b = b.strip_suffix(&[0]).unwrap_or(b);
        std::str::from_utf8(b).map(str::to_owned).map_err(|_| self.err(format!("{what} is not UTF-8")))
    }

    fn header(&mut self) -> Result<Header, String> {
        let sec = self.i32("header.stamp.sec")?;
        let nanosec = self.u32("header.stamp.nanosec")?;
        let frame_id = self.string("header.frame_id")?;
        Ok(Header { stamp: Time { sec, nanosec }, frame_id })
    }

    fn vector3(&mut self, what: &str) -> Result<Vector3, String> {
        Ok(Vector3 { x: self.f64(what)?, y: self.f64(what)?, z: self.f64(what)? })
    }

    fn quaternion(&mut self, what: &str) -> Result<Quaternion, String> {
        Ok(Quaternion { x: self.f64(what)?, y: self.f64(what)?, z: self.f64(what)?, w: self.f64(what)? })
    }

    /// A `sensor_msgs/msg/PointCloud2`.
    pub fn point_cloud(&mut self) -> Result<CloudMsg<'a>, String> {
        let header = self.header()?;
        let height = self.u32("height")?;
        let width = self.u32("width")?;
        // A PointField takes at least 13 bytes (name length, offset,
        // datatype, count).
        let n = self.len("fields", 13)?;
        let mut fields = Vec::with_capacity(n);
        for _ in 0..n {
            let name = self.string("field name")?;
            let offset = self.u32("field offset")?;
            let datatype = self.u8("field datatype")?;
            let count = self.u32("field count")?;
            fields.push((name, offset, datatype, count));
        }
        let is_bigendian = self.bool("is_bigendian")?;
        let point_step = self.u32("point_step")?;
        let row_step = self.u32("row_step")?;
        let len = self.len("data", 1)?;
        let data = self.take(len, "data")?;
        Ok(CloudMsg { header, height, width, fields, is_bigendian, point_step, row_step, data })
    }

    /// A `tf2_msgs/msg/TFMessage`.
    pub fn tf_message(&mut self) -> Result<Vec<TransformStamped>, String> {
        // A TransformStamped takes at least 69 bytes.
        let n = self.len("transforms", 69)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            let header = self.header()?;
            let child_frame_id = self.string("child_frame_id")?;
            let translation = self.vector3("translation")?;
            let rotation = self.quaternion("rotation")?;
            out.push(TransformStamped { header, child_frame_id, transform: Transform { translation, rotation } });
        }
        Ok(out)
    }

    /// A `nav_msgs/msg/Odometry`'s header, child frame and pose (the
    /// covariance and twist after it are not read).
    pub fn odometry_pose(&mut self) -> Result<TransformStamped, String> {
        let header = self.header()?;
        let child_frame_id = self.string("child_frame_id")?;
        let translation = self.vector3("pose.position")?;
        let rotation = self.quaternion("pose.orientation")?;
        Ok(TransformStamped { header, child_frame_id, transform: Transform { translation, rotation } })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sources::ros_msgs::{PointCloud2, PointField, TfMessage};

    fn cloud() -> PointCloud2 {
        PointCloud2 {
            header: Header { stamp: Time { sec: 3, nanosec: 5 }, frame_id: "velodyne".into() },
            height: 1,
            width: 2,
            fields: vec![PointField { name: "x".into(), offset: 0, datatype: 7, count: 1 }],
            is_bigendian: false,
            point_step: 4,
            row_step: 8,
            data: vec![0, 0, 128, 63, 0, 0, 0, 64],
            is_dense: true,
        }
    }

    #[test]
    fn decodes_what_the_cdr_crate_encodes_in_both_byte_orders() {
        let pc = cloud();
        for bytes in [
            cdr::serialize::<_, _, cdr::CdrLe>(&pc, cdr::Infinite).unwrap(),
            cdr::serialize::<_, _, cdr::CdrBe>(&pc, cdr::Infinite).unwrap(),
        ] {
            let got = Cdr::new(&bytes).unwrap().point_cloud().unwrap();
            assert_eq!(got.header, pc.header);
            assert_eq!((got.height, got.width, got.point_step, got.row_step), (1, 2, 4, 8));
            assert_eq!(got.fields, vec![("x".to_string(), 0, 7, 1)]);
            assert_eq!(got.data, &pc.data[..]);
        }
        let tf = TfMessage {
            transforms: vec![TransformStamped {
                header: Header { stamp: Time { sec: -1, nanosec: 7 }, frame_id: "world".into() },
                child_frame_id: "velodyne".into(),
                transform: Transform {
                    translation: Vector3 { x: 1.0, y: 2.0, z: 3.0 },
                    rotation: Quaternion { x: 0.0, y: 0.0, z: 0.6, w: 0.8 },
                },
            }],
        };
        let bytes = cdr::serialize::<_, _, cdr::CdrLe>(&tf, cdr::Infinite).unwrap();
        assert_eq!(Cdr::new(&bytes).unwrap().tf_message().unwrap(), tf.transforms);
    }

    #[test]
    fn a_length_beyond_the_message_is_an_error_before_any_allocation() {
        let mut bytes = cdr::serialize::<_, _, cdr::CdrLe>(&cloud(), cdr::Infinite).unwrap();
        // frame_id's length (after the 4-byte header and the 8-byte stamp).
        bytes[12..16].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        let e = Cdr::new(&bytes).unwrap().point_cloud().unwrap_err();
        assert!(e.contains("header.frame_id") && e.contains("byte 12"), "{e}");
        for cut in 0..bytes.len() {
            let _ = Cdr::new(&bytes[..cut]).and_then(|mut c| c.point_cloud());
        }
    }
}
