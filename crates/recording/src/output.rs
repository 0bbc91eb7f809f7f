//! Keyframes written as a `loop` folder: `sequence/NNNNNN.{jpg,png}` in
//! keyframe order, `sequence_poses.txt` (TUM: time, position,
//! orientation), the layout `humem eval` reads, and where the recording
//! holds the camera's intrinsics, `sequence_calib.json` (what the
//! ORB-SLAM3 harness builds its camera settings from).
//!
//! The folder is built beside its destination under a temporary name and
//! renamed into place once every file is written, so a failure half way
//! leaves nothing that looks like a data set.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::error::RecordingError;
use crate::messages::CameraInfo;
use crate::pose::Pose;

/// A keyframe's image as the source holds it.
pub enum FrameImage {
    /// An image file to copy (JPEG or PNG).
    File(PathBuf),
    /// An encoded image's bytes, with the extension of its format.
    Encoded(Vec<u8>, &'static str),
    /// Decoded pixels, written as PNG (lossless).
    Pixels(image::DynamicImage),
}

/// A `loop` folder being written.
pub struct LoopFolder {
    partial: PathBuf,
    out: PathBuf,
    poses: String,
    calibration: Option<serde_json::Value>,
    written: usize,
}

impl LoopFolder {
    /// Starts a folder that [`LoopFolder::finish`] puts at `out`, which
    /// must not exist.
    pub fn create(out: &Path) -> Result<LoopFolder, RecordingError> {
        if out.exists() {
            return Err(RecordingError::Layout {
                path: out.to_path_buf(),
                reason: "already exists; remove it or name another folder".into(),
            });
        }
        let name = out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "recording".into());
        let partial = out.with_file_name(format!(".{name}.partial-{}", std::process::id()));
        if partial.exists() {
            std::fs::remove_dir_all(&partial).map_err(RecordingError::io(&partial))?;
        }
        let sequence = partial.join("sequence");
        std::fs::create_dir_all(&sequence).map_err(RecordingError::io(&sequence))?;
        Ok(LoopFolder {
            partial,
            out: out.to_path_buf(),
            poses: "# timestamp tx ty tz qx qy qz qw  (written by humem from a recording)\n".into(),
            calibration: None,
            written: 0,
        })
    }

    /// Adds the next keyframe.
    pub fn push(
        &mut self,
        time: f64,
        pose: &Pose,
        image: FrameImage,
    ) -> Result<(), RecordingError> {
        let stem = self
            .partial
            .join("sequence")
            .join(format!("{:06}", self.written));
        match image {
            FrameImage::File(source) => {
                let ext = source
                    .extension()
                    .map(|e| e.to_string_lossy().to_ascii_lowercase())
                    .unwrap_or_else(|| "png".into());
                let target = stem.with_extension(ext);
                std::fs::copy(&source, &target).map_err(RecordingError::io(&source))?;
            }
            FrameImage::Encoded(bytes, ext) => {
                let target = stem.with_extension(ext);
                std::fs::write(&target, bytes).map_err(RecordingError::io(&target))?;
            }
            FrameImage::Pixels(pixels) => {
                let target = stem.with_extension("png");
                pixels
                    .save_with_format(&target, image::ImageFormat::Png)
                    .map_err(|e| RecordingError::Io {
                        path: target.clone(),
                        source: std::io::Error::other(e),
                    })?;
            }
        }
        let q = pose.r.quaternion();
        writeln!(
            self.poses,
            "{time:.9} {} {} {} {} {} {} {}",
            pose.t.x, pose.t.y, pose.t.z, q.i, q.j, q.k, q.w
        )
        .expect("writing to a String");
        self.written += 1;
        Ok(())
    }

    /// Writes `info` (read from `source`) as the folder's
    /// `sequence_calib.json` when it is finished.
    pub fn set_calibration(&mut self, info: &CameraInfo, source: &str) {
        let k = &info.k;
        let mut calibration = serde_json::json!({
            "width": info.width,
            "height": info.height,
            "fx": k[0],
            "fy": k[4],
            "cx": k[2],
            "cy": k[5],
            "model": if info.distortion_model.is_empty() {
                "pinhole".to_string()
            } else {
                format!("pinhole, {}", info.distortion_model)
            },
            "camera_frame": info.header.frame_id,
            "source": source,
        });
        if !info.d.is_empty() {
            let d = |i: usize| info.d.get(i).copied().unwrap_or(0.0);
            calibration["distortion"] = if matches!(
                info.distortion_model.as_str(),
                "plumb_bob" | ""
            ) && info.d.len() <= 5
            {
                serde_json::json!({ "k1": d(0), "k2": d(1), "p1": d(2), "p2": d(3), "k3": d(4) })
            } else {
                serde_json::json!({ "coefficients": info.d })
            };
        }
        self.calibration = Some(calibration);
    }

    /// Keyframes pushed so far.
    pub fn len(&self) -> usize {
        self.written
    }

    /// Whether no keyframe was pushed.
    pub fn is_empty(&self) -> bool {
        self.written == 0
    }

    /// Writes the poses and puts the folder in place.
    pub fn finish(self) -> Result<usize, RecordingError> {
        let poses = self.partial.join("sequence_poses.txt");
        std::fs::write(&poses, &self.poses).map_err(RecordingError::io(&poses))?;
        if let Some(calibration) = &self.calibration {
            let path = self.partial.join("sequence_calib.json");
            let text = serde_json::to_string_pretty(calibration).expect("a JSON value prints");
            std::fs::write(&path, text + "\n").map_err(RecordingError::io(&path))?;
        }
        std::fs::rename(&self.partial, &self.out).map_err(RecordingError::io(&self.out))?;
        Ok(self.written)
    }
}

impl Drop for LoopFolder {
    /// A folder dropped before [`LoopFolder::finish`] is removed.
    fn drop(&mut self) {
        if self.partial.exists() {
            let _ = std::fs::remove_dir_all(&self.partial);
        }
    }
}
