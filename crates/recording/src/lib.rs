//! Recordings into HuMem: a robot's drive, as it sits on a disk, turned
//! into the keyframes and poses HuMem's evaluation and ingestion read.
//!
//! A team trying HuMem starts from what it already has: a ROS 2 bag in
//! MCAP, a ROS 1 `.bag`, or a data set in the TUM RGB-D, EuRoC/ASL or KITTI
//! odometry layout. Each is read without ROS ([`bag`], [`layouts`]) into
//! the same two streams, images and poses with their times; [`align`]
//! gives each image the pose at its time (interpolated between the poses
//! on either side, within a tolerance) and keeps the keyframes a
//! distance/angle/time rule picks; [`output`] writes them as a `loop`
//! folder (`sequence/` and `sequence_poses.txt`), the layout `humem eval`
//! already reads. So every source goes through one evaluation path and
//! gives the figures the same frames in a folder give.
//!
//! The crate knows nothing of HuMem's models or index: it only moves
//! pixels and poses, and names the topic, message or line when they are
//! wrong.

pub mod align;
pub mod bag;
pub mod layouts;
pub mod messages;
pub mod output;

use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};

pub use align::KeyframeRule;

/// A camera pose: position and orientation in the recording's world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position, metres.
    pub t: Vector3<f64>,
    /// Orientation.
    pub r: UnitQuaternion<f64>,
}

/// A pose at a time (seconds).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedPose {
    /// Seconds.
    pub time: f64,
    /// The pose then.
    pub pose: Pose,
}

/// The kinds of recording read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// A ROS 2 bag in MCAP: a `.mcap` file, or a rosbag2 folder of them.
    Ros2Mcap,
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
    /// Bags: take poses from `/tf` and `/tf_static`, the transform from
    /// the first frame to the second (a direct edge of the tree).
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
    /// Images read.
    pub images: usize,
    /// Images left out because no pose lay within the tolerance.
    pub without_pose: usize,
    /// Keyframes written.
    pub keyframes: usize,
}

/// Why a recording could not be read.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// The path is none of the recordings this crate reads.
    #[error("{path}: not a recording HuMem reads ({reason})")]
    UnknownFormat {
        /// The path.
        path: PathBuf,
        /// What was looked for.
        reason: String,
    },
    /// The bag itself is damaged (truncated, bad record).
    #[error("{path}: damaged bag: {reason}")]
    Damaged {
        /// The bag.
        path: PathBuf,
        /// What the reader found.
        reason: String,
    },
    /// A topic asked for is not in the bag, or none fits.
    #[error("{path}: {reason}; the bag's topics: {topics}")]
    Topic {
        /// The bag.
        path: PathBuf,
        /// What is missing or ambiguous.
        reason: String,
        /// Every topic with its type.
        topics: String,
    },
    /// A message that cannot be used.
    #[error("{path}: topic {topic}, message {index}: {reason}")]
    Message {
        /// The bag.
        path: PathBuf,
        /// Its topic.
        topic: String,
        /// 0-based index of the message on its topic.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// A line of a text file that cannot be used.
    #[error("{path}, line {line}: {reason}")]
    Line {
        /// The file.
        path: PathBuf,
        /// 1-based.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// Something else about the layout (missing folder, counts disagree).
    #[error("{path}: {reason}")]
    Layout {
        /// Where.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// No image has a pose within the tolerance.
    #[error("no image from {images} has a pose from {poses} within {tolerance} s ({detail})")]
    NoPose {
        /// Where the images came from.
        images: String,
        /// Where the poses came from.
        poses: String,
        /// The tolerance, seconds.
        tolerance: f64,
        /// The time spans, to see the mismatch.
        detail: String,
    },
}

impl RecordingError {
    pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> RecordingError + '_ {
        move |source| RecordingError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// What kind of recording `path` is, by its name and contents.
pub fn detect(path: &Path) -> Result<Format, RecordingError> {
    let unknown = |reason: &str| RecordingError::UnknownFormat {
        path: path.to_path_buf(),
        reason: reason.into(),
    };
    if path.is_file() {
        return match path.extension().and_then(|e| e.to_str()) {
            Some("mcap") => Ok(Format::Ros2Mcap),
            Some("bag") => Ok(Format::Ros1Bag),
            _ => Err(unknown("a file must be a .mcap or a .bag")),
        };
    }
    if !path.is_dir() {
        return Err(RecordingError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::from(std::io::ErrorKind::NotFound),
        });
    }
    let has = |name: &str| path.join(name).exists();
    if has("sequence") || (has("query") && has("reference")) {
        Ok(Format::Folder)
    } else if has("metadata.yaml") {
        Ok(Format::Ros2Mcap)
    } else if has("rgb.txt") {
        Ok(Format::Tum)
    } else if has("mav0") || (has("cam0") && has("state_groundtruth_estimate0")) {
        Ok(Format::Euroc)
    } else if has("sequences") || has("times.txt") {
        Ok(Format::Kitti)
    } else {
        Err(unknown(
            "looked for a rosbag2 folder (metadata.yaml), TUM (rgb.txt), EuRoC (mav0/), \
             KITTI (sequences/ or times.txt) or a HuMem folder (sequence/, or query/ and reference/)",
        ))
    }
}

/// Reads the recording at `source` and writes its keyframes as a `loop`
/// folder at `out` (`sequence/NNNNNN.{jpg,png}` and `sequence_poses.txt`),
/// which must not exist yet. Nothing is left at `out` when it fails.
pub fn extract(source: &Path, options: &Options, out: &Path) -> Result<Summary, RecordingError> {
    let format = detect(source)?;
    match format {
        Format::Ros2Mcap | Format::Ros1Bag => bag::extract(source, format, options, out),
        Format::Tum | Format::Euroc | Format::Kitti => {
            layouts::extract(source, format, options, out)
        }
        Format::Folder => Err(RecordingError::Layout {
            path: source.to_path_buf(),
            reason: "already a HuMem data set folder: read it as it is".into(),
        }),
    }
}
