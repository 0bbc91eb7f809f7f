//! Recordings into HuMem: a robot's drive, as it sits on a disk, turned
//! into the keyframes and poses HuMem's evaluation and ingestion read.
//!
//! A team trying HuMem starts from what it already has: a ROS 2 bag in
//! MCAP or SQLite, a ROS 1 `.bag`, or a data set in the TUM RGB-D, EuRoC/ASL or KITTI
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
//!
//! The types every module shares sit in leaf modules and are re-exported
//! here: [`pose`] (a pose, and a pose at a time), [`error`]
//! ([`RecordingError`]) and [`extraction`] (the [`Format`], the
//! [`Options`] and the [`Summary`] of one extraction). No module uses this
//! root; it only detects the format and hands the recording to its reader.

pub mod align;
pub mod bag;
mod bag_storage;
pub mod error;
pub mod extraction;
pub mod layouts;
pub mod messages;
pub mod output;
pub mod pose;
pub mod tf_tree;

use std::path::Path;

pub use align::KeyframeRule;
pub use error::RecordingError;
pub use extraction::{Format, Options, Summary};
pub use pose::{Pose, TimedPose};

/// What kind of recording `path` is, by its name and contents.
pub fn detect(path: &Path) -> Result<Format, RecordingError> {
    let unknown = |reason: &str| RecordingError::UnknownFormat {
        path: path.to_path_buf(),
        reason: reason.into(),
    };
    if path.is_file() {
        return match path.extension().and_then(|e| e.to_str()) {
            Some("mcap") => Ok(Format::Ros2Mcap),
            Some("db3") => Ok(Format::Ros2Sqlite),
            Some("bag") => Ok(Format::Ros1Bag),
            _ => Err(unknown("a file must be a .mcap, a .db3 or a .bag")),
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
        bag_storage::rosbag2_format(path)
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
        Format::Ros2Mcap | Format::Ros2Sqlite | Format::Ros1Bag => {
            bag::extract(source, format, options, out)
        }
        Format::Tum | Format::Euroc | Format::Kitti => {
            layouts::extract(source, format, options, out)
        }
        Format::Folder => Err(RecordingError::Layout {
            path: source.to_path_buf(),
            reason: "already a HuMem data set folder: read it as it is".into(),
        }),
    }
}
