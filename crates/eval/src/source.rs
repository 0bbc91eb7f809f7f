//! `--source`: a recording (a ROS 1 or ROS 2 bag, a TUM RGB-D, EuRoC or
//! KITTI folder) as the data set of `humem eval` and `humem ingest`.
//!
//! The recording is cut into keyframes by `humem-recording` and written as
//! a `loop` folder, so that everything after (ground truth by the paper's
//! rule, the protocol, the report) is the folder path that every data set
//! takes, and a drive gives the same figures in any format. The folder is
//! temporary unless `--keep-frames` names where to keep it.

use std::path::{Path, PathBuf};

use anyhow::Context;
use humem_recording::{Format, KeyframeRule, Options};

/// How a recording is read (`humem eval --source`, `humem ingest`).
#[derive(Debug, Clone, clap::Args)]
pub struct SourceArgs {
    /// A recording: a ROS 2 bag (a .mcap or .db3 file, or a rosbag2
    /// folder), a ROS 1
    /// .bag, a TUM RGB-D, EuRoC/ASL or KITTI odometry folder, or a HuMem
    /// data set folder.
    #[arg(long, value_name = "PATH")]
    pub source: Option<PathBuf>,
    /// Bags: the image topic (sensor_msgs/Image or CompressedImage);
    /// default: the only one.
    #[arg(long)]
    pub image_topic: Option<String>,
    /// Bags: the pose topic (nav_msgs/Odometry or
    /// geometry_msgs/PoseStamped); default: the only one. An odometry of
    /// the body is moved to the camera by the mounting on /tf_static.
    #[arg(long)]
    pub pose_topic: Option<String>,
    /// Bags: poses from /tf and /tf_static, the pose of CHILD in PARENT
    /// (e.g. map,camera_optical), composed through the tree at each image's
    /// time.
    #[arg(long, value_name = "PARENT,CHILD")]
    pub tf_frames: Option<String>,
    /// Largest time between an image and the poses it gets, seconds
    /// (interpolated between the poses either side).
    #[arg(long, default_value_t = 0.1)]
    pub pose_tolerance: f64,
    /// A new keyframe after moving this far, metres (0: off; all three
    /// keyframe rules 0: every image).
    #[arg(long, default_value_t = 0.5)]
    pub keyframe_distance: f64,
    /// A new keyframe after turning this far, degrees (0: off).
    #[arg(long, default_value_t = 15.0)]
    pub keyframe_angle: f64,
    /// A new keyframe after this long, seconds (0: off).
    #[arg(long, default_value_t = 0.0)]
    pub keyframe_interval: f64,
    /// KITTI: the sequence (00, 01, …); default: the only one with poses.
    #[arg(long)]
    pub sequence: Option<String>,
    /// KITTI: the image folder (image_0 … image_3); EuRoC: the camera
    /// (cam0, cam1).
    #[arg(long)]
    pub camera: Option<String>,
    /// Keep the keyframes taken from the recording here, as a HuMem data
    /// set folder (it must not exist); default: a temporary folder.
    #[arg(long, value_name = "DIR")]
    pub keep_frames: Option<PathBuf>,
}

/// A recording's keyframes in a `loop` folder, and the temporary folder
/// that holds it while it is needed.
pub struct Materialized {
    /// The data set folder.
    pub folder: PathBuf,
    /// What was read, for the log; `None` for a folder read as it is.
    pub summary: Option<humem_recording::Summary>,
    _temporary: Option<tempfile::TempDir>,
}

impl SourceArgs {
    /// The reading options these arguments say.
    pub fn options(&self) -> anyhow::Result<Options> {
        let tf_frames = match &self.tf_frames {
            None => None,
            Some(pair) => match pair.split_once(',') {
                Some((parent, child)) if !parent.is_empty() && !child.is_empty() => {
                    Some((parent.trim().to_string(), child.trim().to_string()))
                }
                _ => anyhow::bail!("--tf-frames takes two frames, PARENT,CHILD (not {pair:?})"),
            },
        };
        anyhow::ensure!(
            self.pose_tolerance >= 0.0,
            "--pose-tolerance must not be negative"
        );
        Ok(Options {
            image_topic: self.image_topic.clone(),
            pose_topic: self.pose_topic.clone(),
            tf_frames,
            pose_tolerance: self.pose_tolerance,
            keyframes: KeyframeRule {
                min_distance_m: self.keyframe_distance,
                min_angle_deg: self.keyframe_angle,
                max_interval_s: self.keyframe_interval,
            },
            sequence: self.sequence.clone(),
            camera: self.camera.clone(),
        })
    }

    /// The recording at `source` as a data set folder: the folder itself
    /// when it already is one, else its keyframes written into
    /// `--keep-frames` or a temporary folder.
    pub fn materialize(&self, source: &Path) -> anyhow::Result<Materialized> {
        let format = humem_recording::detect(source)?;
        if format == Format::Folder {
            return Ok(Materialized {
                folder: source.to_path_buf(),
                summary: None,
                _temporary: None,
            });
        }
        let options = self.options()?;
        let name = source
            .file_stem()
            .map(|n| n.to_string_lossy().into_owned())
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| "recording".into());
        let (folder, temporary) = match &self.keep_frames {
            Some(dir) => (dir.clone(), None),
            None => {
                let temporary = tempfile::Builder::new()
                    .prefix("humem-recording-")
                    .tempdir()
                    .context("making a temporary folder for the recording's keyframes")?;
                (temporary.path().join(&name), Some(temporary))
            }
        };
        eprintln!(
            "humem: reading {} ({format}) into keyframes",
            source.display()
        );
        let summary = humem_recording::extract(source, &options, &folder)
            .with_context(|| format!("reading the recording {}", source.display()))?;
        eprintln!(
            "humem: {} keyframes of {} images from {} (poses: {}; {} images had no pose within {} s{}){}",
            summary.keyframes,
            summary.images,
            summary.image_source,
            summary.pose_source,
            summary.without_pose,
            options.pose_tolerance,
            summary
                .calibration_source
                .as_ref()
                .map(|c| format!("; intrinsics: {c}"))
                .unwrap_or_default(),
            self.keep_frames
                .as_ref()
                .map(|d| format!(", kept in {}", d.display()))
                .unwrap_or_default()
        );
        Ok(Materialized {
            folder,
            summary: Some(summary),
            _temporary: temporary,
        })
    }
}
