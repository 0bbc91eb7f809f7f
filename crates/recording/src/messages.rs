//! The few ROS messages a recording needs, decoded from their bytes in a
//! bag: `sensor_msgs/Image`, `sensor_msgs/CompressedImage`,
//! `sensor_msgs/CameraInfo`, `nav_msgs/Odometry`,
//! `geometry_msgs/PoseStamped` and `tf2_msgs/TFMessage`.
//!
//! ROS 1 and ROS 2 lay these out almost alike: little-endian numbers,
//! length-prefixed strings and sequences. ROS 2's CDR aligns every number
//! to its size (counted from after the 4-byte encapsulation header) and
//! ends strings with a NUL; ROS 1 packs and its header carries a sequence
//! number. One [`Reader`] with a [`Dialect`] reads both, so each message is
//! written once. Only the fields HuMem uses are kept; the rest are read
//! past, which also checks the message is as long as its type says.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::pose::Pose;

/// How a bag serialises its messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dialect {
    /// ROS 1 (`.bag`): packed, `Header` with `seq`.
    Ros1,
    /// ROS 2 CDR (`cdr` in MCAP): aligned, NUL-terminated strings.
    Cdr,
}

/// Why a message could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MessageError {
    /// The bytes end before the type's fields do.
    #[error("truncated: needs {needed} bytes at offset {at}, has {len}")]
    Truncated {
        /// Offset of the field.
        at: usize,
        /// Bytes the field needs.
        needed: usize,
        /// Bytes in the message.
        len: usize,
    },
    /// A CDR message that is not little-endian CDR.
    #[error("CDR encapsulation {0:#06x} is not little-endian CDR (0x0001)")]
    Encapsulation(u16),
    /// A string that is not UTF-8.
    #[error("a string field is not UTF-8")]
    Utf8,
}

/// Reads a message's fields in order.
pub struct Reader<'a> {
    data: &'a [u8],
    at: usize,
    /// Where CDR alignment counts from.
    origin: usize,
    dialect: Dialect,
}

impl<'a> Reader<'a> {
    /// A reader at the first field of `data`.
    pub fn new(data: &'a [u8], dialect: Dialect) -> Result<Self, MessageError> {
        let mut reader = Reader {
            data,
            at: 0,
            origin: 0,
            dialect,
        };
        if dialect == Dialect::Cdr {
            let kind = u16::from_be_bytes(reader.take(2)?.try_into().expect("two bytes"));
            reader.take(2)?;
            if kind != 0x0001 {
                return Err(MessageError::Encapsulation(kind));
            }
            reader.origin = 4;
        }
        Ok(reader)
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], MessageError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.data.len());
        let Some(end) = end else {
            return Err(MessageError::Truncated {
                at: self.at,
                needed: n,
                len: self.data.len(),
            });
        };
        let bytes = &self.data[self.at..end];
        self.at = end;
        Ok(bytes)
    }

    fn align(&mut self, size: usize) -> Result<(), MessageError> {
        if self.dialect == Dialect::Cdr {
            let offset = (self.at - self.origin) % size;
            if offset != 0 {
                self.take(size - offset)?;
            }
        }
        Ok(())
    }

    fn u8(&mut self) -> Result<u8, MessageError> {
        Ok(self.take(1)?[0])
    }

    fn u32(&mut self) -> Result<u32, MessageError> {
        self.align(4)?;
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4")))
    }

    fn f64(&mut self) -> Result<f64, MessageError> {
        self.align(8)?;
        Ok(f64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }

    fn string(&mut self) -> Result<String, MessageError> {
        let len = self.u32()? as usize;
        let bytes = self.take(len)?;
        // CDR counts and stores the terminating NUL.
        let bytes = match self.dialect {
            Dialect::Cdr => bytes.strip_suffix(&[0]).unwrap_or(bytes),
            Dialect::Ros1 => bytes,
        };
        String::from_utf8(bytes.to_vec()).map_err(|_| MessageError::Utf8)
    }

    fn bytes(&mut self) -> Result<&'a [u8], MessageError> {
        let len = self.u32()? as usize;
        self.take(len)
    }

    /// `std_msgs/Header`: the stamp in seconds and the frame id.
    fn header(&mut self) -> Result<Header, MessageError> {
        if self.dialect == Dialect::Ros1 {
            self.u32()?; // seq
        }
        let sec = self.u32()?;
        let nanosec = self.u32()?;
        let frame_id = self.string()?;
        Ok(Header {
            stamp: f64::from(sec) + f64::from(nanosec) * 1e-9,
            frame_id,
        })
    }

    fn vector3(&mut self) -> Result<Vector3<f64>, MessageError> {
        Ok(Vector3::new(self.f64()?, self.f64()?, self.f64()?))
    }

    /// A `geometry_msgs` quaternion (x, y, z, w), normalised.
    fn quaternion(&mut self) -> Result<UnitQuaternion<f64>, MessageError> {
        let (x, y, z, w) = (self.f64()?, self.f64()?, self.f64()?, self.f64()?);
        Ok(UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)))
    }

    fn pose(&mut self) -> Result<Pose, MessageError> {
        Ok(Pose {
            t: self.vector3()?,
            r: self.quaternion()?,
        })
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    /// The stamp, seconds.
    pub stamp: f64,
    /// The frame the data is in.
    pub frame_id: String,
}

/// `sensor_msgs/Image`.
#[derive(Debug, Clone, PartialEq)]
pub struct RawImage {
    /// Its header.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`rgb8`, `bgr8`, `mono8`, …).
    pub encoding: String,
    /// Whether multi-byte pixels are big-endian.
    pub big_endian: bool,
    /// Bytes per row.
    pub step: u32,
    /// The pixels.
    pub data: Vec<u8>,
}

/// `sensor_msgs/CompressedImage`.
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedImage {
    /// Its header.
    pub header: Header,
    /// `jpeg`, `png`, or a longer description that names one.
    pub format: String,
    /// The file's bytes.
    pub data: Vec<u8>,
}

/// A stamped pose from `nav_msgs/Odometry` or `geometry_msgs/PoseStamped`.
#[derive(Debug, Clone, PartialEq)]
pub struct StampedPose {
    /// Its header.
    pub header: Header,
    /// The child frame (Odometry), empty for PoseStamped.
    pub child_frame_id: String,
    /// The pose of the child frame in the header's frame.
    pub pose: Pose,
}

/// The header of a message that starts with a `std_msgs/Header`, reading
/// nothing past it.
pub fn header(data: &[u8], dialect: Dialect) -> Result<Header, MessageError> {
    Reader::new(data, dialect)?.header()
}

/// `sensor_msgs/CameraInfo`: the image size and the intrinsics (the
/// rectification and projection matrices, binning and region of interest
/// are read past).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// Its header: the camera's optical frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// `plumb_bob`, `rational_polynomial`, `equidistant`, or empty.
    pub distortion_model: String,
    /// The distortion coefficients (`plumb_bob`: k1, k2, p1, p2, k3).
    pub d: Vec<f64>,
    /// The camera matrix, row-major: fx 0 cx / 0 fy cy / 0 0 1.
    pub k: [f64; 9],
}

/// Decodes a `sensor_msgs/CameraInfo`.
pub fn camera_info(data: &[u8], dialect: Dialect) -> Result<CameraInfo, MessageError> {
    let mut r = Reader::new(data, dialect)?;
    let header = r.header()?;
    let height = r.u32()?;
    let width = r.u32()?;
    let distortion_model = r.string()?;
    let n = r.u32()? as usize;
    let mut d = Vec::with_capacity(n.min(64));
    for _ in 0..n {
        d.push(r.f64()?);
    }
    let mut k = [0.0; 9];
    for v in &mut k {
        *v = r.f64()?;
    }
    // R (9), P (12), binning x and y, and the region of interest
    // (x, y, height, width offsets and do_rectify).
    for _ in 0..21 {
        r.f64()?;
    }
    for _ in 0..6 {
        r.u32()?;
    }
    r.u8()?;
    Ok(CameraInfo {
        header,
        height,
        width,
        distortion_model,
        d,
        k,
    })
}

/// Decodes a `sensor_msgs/Image`.
pub fn image(data: &[u8], dialect: Dialect) -> Result<RawImage, MessageError> {
    let mut r = Reader::new(data, dialect)?;
    Ok(RawImage {
        header: r.header()?,
        height: r.u32()?,
        width: r.u32()?,
        encoding: r.string()?,
        big_endian: r.u8()? != 0,
        step: r.u32()?,
        data: r.bytes()?.to_vec(),
    })
}

/// Decodes a `sensor_msgs/CompressedImage`.
pub fn compressed_image(data: &[u8], dialect: Dialect) -> Result<CompressedImage, MessageError> {
    let mut r = Reader::new(data, dialect)?;
    Ok(CompressedImage {
        header: r.header()?,
        format: r.string()?,
        data: r.bytes()?.to_vec(),
    })
}

/// Decodes the header and pose of a `nav_msgs/Odometry` (the covariance
/// and the twist are read past).
pub fn odometry(data: &[u8], dialect: Dialect) -> Result<StampedPose, MessageError> {
    let mut r = Reader::new(data, dialect)?;
    let header = r.header()?;
    let child_frame_id = r.string()?;
    let pose = r.pose()?;
    for _ in 0..36 {
        r.f64()?;
    }
    // Twist with covariance: 6 + 36 numbers.
    for _ in 0..42 {
        r.f64()?;
    }
    Ok(StampedPose {
        header,
        child_frame_id,
        pose,
    })
}

/// Decodes a `geometry_msgs/PoseStamped`.
pub fn pose_stamped(data: &[u8], dialect: Dialect) -> Result<StampedPose, MessageError> {
    let mut r = Reader::new(data, dialect)?;
    Ok(StampedPose {
        header: r.header()?,
        child_frame_id: String::new(),
        pose: r.pose()?,
    })
}

/// Decodes a `tf2_msgs/TFMessage`: each transform as the pose of its
/// child frame in its header's frame.
pub fn tf_message(data: &[u8], dialect: Dialect) -> Result<Vec<StampedPose>, MessageError> {
    let mut r = Reader::new(data, dialect)?;
    let count = r.u32()?;
    let mut out = Vec::new();
    for _ in 0..count {
        let header = r.header()?;
        let child_frame_id = r.string()?;
        let pose = r.pose()?;
        out.push(StampedPose {
            header,
            child_frame_id,
            pose,
        });
    }
    Ok(out)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Writes fields as a dialect lays them out, to build test messages.
    pub(crate) struct Writer {
        pub(crate) data: Vec<u8>,
        origin: usize,
        dialect: Dialect,
    }

    impl Writer {
        pub(crate) fn new(dialect: Dialect) -> Self {
            let data = match dialect {
                Dialect::Cdr => vec![0, 1, 0, 0],
                Dialect::Ros1 => Vec::new(),
            };
            let origin = data.len();
            Writer {
                data,
                origin,
                dialect,
            }
        }
        fn align(&mut self, size: usize) {
            if self.dialect == Dialect::Cdr {
                while !(self.data.len() - self.origin).is_multiple_of(size) {
                    self.data.push(0);
                }
            }
        }
        pub(crate) fn u8(&mut self, v: u8) {
            self.data.push(v);
        }
        pub(crate) fn u32(&mut self, v: u32) {
            self.align(4);
            self.data.extend_from_slice(&v.to_le_bytes());
        }
        pub(crate) fn f64(&mut self, v: f64) {
            self.align(8);
            self.data.extend_from_slice(&v.to_le_bytes());
        }
        pub(crate) fn string(&mut self, s: &str) {
            let nul = usize::from(self.dialect == Dialect::Cdr);
            self.u32((s.len() + nul) as u32);
            self.data.extend_from_slice(s.as_bytes());
            if nul == 1 {
                self.data.push(0);
            }
        }
        pub(crate) fn bytes(&mut self, b: &[u8]) {
            self.u32(b.len() as u32);
            self.data.extend_from_slice(b);
        }
        pub(crate) fn header(&mut self, sec: u32, nsec: u32, frame: &str) {
            if self.dialect == Dialect::Ros1 {
                self.u32(7);
            }
            self.u32(sec);
            self.u32(nsec);
            self.string(frame);
        }
        pub(crate) fn pose(&mut self, t: [f64; 3], q: [f64; 4]) {
            for v in t.into_iter().chain(q) {
                self.f64(v);
            }
        }
    }

    #[test]
    fn an_image_reads_alike_in_both_dialects() {
        for dialect in [Dialect::Ros1, Dialect::Cdr] {
            let mut w = Writer::new(dialect);
            w.header(12, 500_000_000, "cam");
            w.u32(2);
            w.u32(3);
            w.string("rgb8");
            w.u8(0);
            w.u32(9);
            w.bytes(&[7; 18]);
            let image = image(&w.data, dialect).unwrap();
            assert_eq!(image.header.stamp, 12.5);
            assert_eq!(image.header.frame_id, "cam");
            assert_eq!((image.height, image.width, image.step), (2, 3, 9));
            assert_eq!(image.encoding, "rgb8");
            assert_eq!(image.data, vec![7; 18]);
        }
    }

    #[test]
    fn a_pose_stamped_and_an_odometry_read_their_pose() {
        for dialect in [Dialect::Ros1, Dialect::Cdr] {
            let mut w = Writer::new(dialect);
            w.header(3, 0, "map");
            w.pose([1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 2.0]);
            let p = pose_stamped(&w.data, dialect).unwrap();
            assert_eq!(p.pose.t, Vector3::new(1.0, 2.0, 3.0));
            assert_eq!(p.pose.r, UnitQuaternion::identity());

            let mut w = Writer::new(dialect);
            w.header(3, 0, "odom");
            w.string("base_link");
            w.pose([4.0, 5.0, 6.0], [0.0, 0.0, 1.0, 0.0]);
            for _ in 0..78 {
                w.f64(0.5);
            }
            let o = odometry(&w.data, dialect).unwrap();
            assert_eq!(o.child_frame_id, "base_link");
            assert_eq!(o.pose.t, Vector3::new(4.0, 5.0, 6.0));
            assert!((o.pose.r.angle() - std::f64::consts::PI).abs() < 1e-12);
        }
    }

    #[test]
    fn a_short_message_is_an_error_not_a_panic() {
        let mut w = Writer::new(Dialect::Cdr);
        w.header(3, 0, "odom");
        w.string("base_link");
        w.pose([4.0, 5.0, 6.0], [0.0, 0.0, 1.0, 0.0]);
        let err = odometry(&w.data, Dialect::Cdr).unwrap_err();
        assert!(matches!(err, MessageError::Truncated { .. }), "{err}");
        assert!(matches!(
            Reader::new(&[0, 0, 0, 0], Dialect::Cdr),
            Err(MessageError::Encapsulation(0))
        ));
    }

    #[test]
    fn a_camera_info_reads_its_size_and_intrinsics() {
        for dialect in [Dialect::Ros1, Dialect::Cdr] {
            let mut w = Writer::new(dialect);
            w.header(5, 0, "camera_optical");
            w.u32(288);
            w.u32(512);
            w.string("plumb_bob");
            w.u32(5);
            for v in [0.1, -0.2, 0.0, 0.0, 0.05] {
                w.f64(v);
            }
            for v in [304.0, 0.0, 256.0, 0.0, 304.0, 144.0, 0.0, 0.0, 1.0] {
                w.f64(v);
            }
            for _ in 0..21 {
                w.f64(1.0);
            }
            for _ in 0..6 {
                w.u32(0);
            }
            w.u8(0);
            let info = camera_info(&w.data, dialect).unwrap();
            assert_eq!(info.header.frame_id, "camera_optical");
            assert_eq!((info.width, info.height), (512, 288));
            assert_eq!(info.distortion_model, "plumb_bob");
            assert_eq!(info.d, vec![0.1, -0.2, 0.0, 0.0, 0.05]);
            assert_eq!(
                (info.k[0], info.k[2], info.k[4], info.k[5]),
                (304.0, 256.0, 304.0, 144.0)
            );
            // One byte short: refused.
            let short = &w.data[..w.data.len() - 1];
            assert!(camera_info(short, dialect).is_err());
        }
    }

    #[test]
    fn tf_messages_list_every_transform() {
        let mut w = Writer::new(Dialect::Cdr);
        w.u32(2);
        for (child, x) in [("base_link", 1.0), ("camera", 2.0)] {
            w.header(1, 0, "map");
            w.string(child);
            w.pose([x, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]);
        }
        let tf = tf_message(&w.data, Dialect::Cdr).unwrap();
        assert_eq!(tf.len(), 2);
        assert_eq!(tf[1].child_frame_id, "camera");
        assert_eq!(tf[1].pose.t.x, 2.0);
    }
}
