//! One extraction's terms: the kind of recording read ([`Format`]), what
//! to read from it and how to cut it ([`Options`]), and what was read and
//! written ([`Summary`]).
//!
//! Every reader takes and gives these, so they sit in a module below the
//! readers rather than in the crate root that calls them.

use crate::align::KeyframeRule;

/// The kinds of recording read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// A ROS 2 bag in MCAP: a `.mcap` file, or a rosbag2 folder of them.
    Ros2Mcap,
    /// A ROS 2 bag in SQLite: a `.db3` file, or a rosbag2 folder of them.
    Ros2Sqlite,
    /// A ROS 1 `.bag` file.
    Ros1Bag,
    /// TUM RGB-D: `rgb.txt` and `groundtruth.txt`.
    Tum,
    /// EuRoC/ASL: `mav0/cam0` and `mav0/state_groundtruth_estimate0`.
    Euroc,
    /// KITTI odometry: `sequences/NN/image_0`, `times.txt`, `poses/NN.txt`.
    Kitti,
    /// HuMem's own `loop`/`pairs` folder: nothing to convert.
    Folder,
}

impl std::fmt::Display for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Format::Ros2Mcap => "ROS 2 bag (MCAP)",
            Format::Ros2Sqlite => "ROS 2 bag (SQLite)",
            Format::Ros1Bag => "ROS 1 bag",
            Format::Tum => "TUM RGB-D",
            Format::Euroc => "EuRoC/ASL",
            Format::Kitti => "KITTI odometry",
            Format::Folder => "HuMem data set folder",
        })
    }
}

/// What to read from a recording, and how to cut it into keyframes.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// Bags: the image topic (`sensor_msgs/Image` or `CompressedImage`);
    /// by default the only one.
    pub image_topic: Option<String>,
    /// Bags: the pose topic (`nav_msgs/Odometry` or
    /// `geometry_msgs/PoseStamped`); by default the only one.
    pub pose_topic: Option<String>,
    /// Bags: take poses from `/tf` and `/tf_static`, the pose of the
    /// second frame in the first, composed through the tree.
    pub tf_frames: Option<(String, String)>,
    /// Largest time between an image and the poses it is given, seconds.
    pub pose_tolerance: f64,
    /// Which images become keyframes.
    pub keyframes: KeyframeRule,
    /// KITTI: the sequence (`00`…); by default the only one with poses.
    pub sequence: Option<String>,
    /// KITTI: the image folder (`image_0` … `image_3`); EuRoC: the camera
    /// (`cam0`, `cam1`).
    pub camera: Option<String>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            image_topic: None,
            pose_topic: None,
            tf_frames: None,
            pose_tolerance: 0.1,
            keyframes: KeyframeRule::default(),
            sequence: None,
            camera: None,
        }
    }
}

/// What [`extract`] read and wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// What the source was.
    pub format: Format,
    /// Where the images came from (a topic, a file).
    pub image_source: String,
    /// Where the poses came from.
    pub pose_source: String,
    /// Where the camera's intrinsics came from (`sequence_calib.json`),
    /// where the recording holds them.
    pub calibration_source: Option<String>,
    /// Images read.
    pub images: usize,
    /// Images left out because no pose lay within the tolerance.
    pub without_pose: usize,
    /// Keyframes written.
    pub keyframes: usize,
}
