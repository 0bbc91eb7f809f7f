//! The data set layouts people already have on disk: TUM RGB-D, EuRoC/ASL
//! and KITTI odometry.
//!
//! Each is a list of image files with times and a list of poses with
//! times, spelled differently: TUM's `rgb.txt` and `groundtruth.txt`
//! (seconds; `tx ty tz qx qy qz qw`), EuRoC's `data.csv` files
//! (nanoseconds; `w x y z` quaternions, the body's pose), KITTI's
//! `times.txt` with one 3×4 `[R|t]` line per image in `poses/NN.txt`.
//! Each reader turns its layout into those two lists and names the file
//! and line of anything it cannot read; the images are copied as they are.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};

use crate::align::{plan, sort_poses};
use crate::error::RecordingError;
use crate::extraction::{Format, Options, Summary};
use crate::output::{FrameImage, LoopFolder};
use crate::pose::{Pose, TimedPose};

/// A layout read: image files with times, and poses.
struct Listing {
    images: Vec<(f64, PathBuf)>,
    poses: Vec<TimedPose>,
    image_source: String,
    pose_source: String,
}

/// Reads a layout into a `loop` folder at `out` (see [`crate::extract`]).
pub fn extract(
    path: &Path,
    format: Format,
    options: &Options,
    out: &Path,
) -> Result<Summary, RecordingError> {
    let mut listing = match format {
        Format::Tum => tum(path)?,
        Format::Euroc => euroc(path, options)?,
        _ => kitti(path, options)?,
    };
    sort_poses(&mut listing.poses);
    let times: Vec<f64> = listing.images.iter().map(|(t, _)| *t).collect();
    let plan = plan(
        &times,
        &listing.poses,
        options.pose_tolerance,
        &options.keyframes,
        &listing.image_source,
        &listing.pose_source,
    )?;
    let mut folder = LoopFolder::create(out)?;
    for &(index, time, pose) in &plan.keyframes {
        let file = listing.images[index].1.clone();
        if !file.is_file() {
            return Err(RecordingError::Layout {
                path: file,
                reason: format!("listed in {} but missing", listing.image_source),
            });
        }
        folder.push(time, &pose, FrameImage::File(file))?;
    }
    let keyframes = folder.finish()?;
    Ok(Summary {
        format,
        image_source: listing.image_source,
        pose_source: listing.pose_source,
        calibration_source: None,
        images: plan.images,
        without_pose: plan.without_pose,
        keyframes,
    })
}

/// The data lines of a text file: 1-based line number and fields, split
/// on commas or white space; `#` comments and blank lines skipped.
fn lines(path: &Path) -> Result<Vec<(usize, Vec<String>)>, RecordingError> {
    let text = std::fs::read_to_string(path).map_err(RecordingError::io(path))?;
    Ok(text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        .map(|(i, l)| {
            (
                i + 1,
                l.split(|c: char| c == ',' || c.is_whitespace())
                    .filter(|f| !f.is_empty())
                    .map(str::to_string)
                    .collect(),
            )
        })
        .collect())
}

/// The first `n` fields of a line as finite numbers.
fn numbers(
    path: &Path,
    line: usize,
    fields: &[String],
    n: usize,
    layout: &str,
) -> Result<Vec<f64>, RecordingError> {
    let bad = |reason: String| RecordingError::Line {
        path: path.to_path_buf(),
        line,
        reason,
    };
    if fields.len() < n {
        return Err(bad(format!(
            "{} fields where {n} are expected ({layout})",
            fields.len()
        )));
    }
    fields[..n]
        .iter()
        .map(|f| {
            f.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(format!("{f:?} is not a number ({layout})")))
        })
        .collect()
}

fn quaternion(w: f64, x: f64, y: f64, z: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
}

/// A list of `time filename` lines: each file, under `dir`, with its
/// time in seconds (`seconds` per unit of the file's times).
fn timed_files(
    list: &Path,
    layout: &str,
    seconds: f64,
    dir: &Path,
) -> Result<Vec<(f64, PathBuf)>, RecordingError> {
    lines(list)?
        .into_iter()
        .map(|(line, fields)| {
            let t = numbers(list, line, &fields, 1, layout)?[0] * seconds;
            let Some(file) = fields.get(1) else {
                return Err(RecordingError::Line {
                    path: list.to_path_buf(),
                    line,
                    reason: "no file name after the timestamp".into(),
                });
            };
            Ok((t, dir.join(file)))
        })
        .collect()
}

/// A list of `time x y z` and a quaternion lines (`w x y z` when
/// `w_first`, else `x y z w`), times in `seconds` per unit.
fn timed_poses(
    file: &Path,
    layout: &str,
    seconds: f64,
    w_first: bool,
) -> Result<Vec<TimedPose>, RecordingError> {
    lines(file)?
        .into_iter()
        .map(|(line, fields)| {
            let v = numbers(file, line, &fields, 8, layout)?;
            let r = if w_first {
                quaternion(v[4], v[5], v[6], v[7])
            } else {
                quaternion(v[7], v[4], v[5], v[6])
            };
            Ok(TimedPose {
                time: v[0] * seconds,
                pose: Pose {
                    t: Vector3::new(v[1], v[2], v[3]),
                    r,
                },
            })
        })
        .collect()
}

/// TUM RGB-D: `rgb.txt` (`timestamp filename`) and `groundtruth.txt`
/// (`timestamp tx ty tz qx qy qz qw`).
fn tum(dir: &Path) -> Result<Listing, RecordingError> {
    let rgb = dir.join("rgb.txt");
    let truth = dir.join("groundtruth.txt");
    if !truth.is_file() {
        return Err(RecordingError::Layout {
            path: dir.to_path_buf(),
            reason: "a TUM folder needs groundtruth.txt beside rgb.txt".into(),
        });
    }
    let images = timed_files(&rgb, "timestamp filename", 1.0, dir)?;
    let poses = timed_poses(&truth, "timestamp tx ty tz qx qy qz qw", 1.0, false)?;
    Ok(Listing {
        images,
        poses,
        image_source: rgb.display().to_string(),
        pose_source: truth.display().to_string(),
    })
}

/// EuRoC/ASL: `mav0/<cam>/data.csv` (`timestamp [ns], filename`, images
/// in `data/`) and `mav0/state_groundtruth_estimate0/data.csv`
/// (`timestamp [ns], x, y, z, qw, qx, qy, qz, …`).
fn euroc(dir: &Path, options: &Options) -> Result<Listing, RecordingError> {
    let mav0 = if dir.join("mav0").is_dir() {
        dir.join("mav0")
    } else {
        dir.to_path_buf()
    };
    let camera = options.camera.as_deref().unwrap_or("cam0");
    let cam_csv = mav0.join(camera).join("data.csv");
    let truth = mav0.join("state_groundtruth_estimate0").join("data.csv");
    for needed in [&cam_csv, &truth] {
        if !needed.is_file() {
            return Err(RecordingError::Layout {
                path: needed.clone(),
                reason: "missing: a EuRoC folder needs mav0/<camera>/data.csv and \
                         mav0/state_groundtruth_estimate0/data.csv"
                    .into(),
            });
        }
    }
    let images = timed_files(
        &cam_csv,
        "timestamp [ns], filename",
        1e-9,
        &mav0.join(camera).join("data"),
    )?;
    let poses = timed_poses(
        &truth,
        "timestamp [ns], x, y, z, qw, qx, qy, qz",
        1e-9,
        true,
    )?;
    Ok(Listing {
        images,
        poses,
        image_source: cam_csv.display().to_string(),
        pose_source: truth.display().to_string(),
    })
}

/// KITTI odometry: a data set root (`sequences/NN/`, `poses/NN.txt`) or
/// one sequence's folder (`times.txt`, `image_0/`, poses in
/// `../../poses/NN.txt`).
fn kitti(dir: &Path, options: &Options) -> Result<Listing, RecordingError> {
    let layout = |path: &Path, reason: String| RecordingError::Layout {
        path: path.to_path_buf(),
        reason,
    };
    let (sequence_dir, poses_file) = if dir.join("sequences").is_dir() {
        let name = match &options.sequence {
            Some(name) => name.clone(),
            None => {
                let mut with_poses: Vec<String> = std::fs::read_dir(dir.join("sequences"))
                    .map_err(RecordingError::io(dir))?
                    .filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| dir.join("poses").join(format!("{n}.txt")).is_file())
                    .collect();
                with_poses.sort();
                match with_poses.as_slice() {
                    [one] => one.clone(),
                    [] => return Err(layout(dir, "no sequence has poses in poses/NN.txt".into())),
                    many => {
                        return Err(layout(
                            dir,
                            format!(
                                "sequences {} have poses; name one with --sequence",
                                many.join(", ")
                            ),
                        ))
                    }
                }
            }
        };
        (
            dir.join("sequences").join(&name),
            dir.join("poses").join(format!("{name}.txt")),
        )
    } else {
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let beside = dir.join("poses.txt");
        let up = dir.join("../../poses").join(format!("{name}.txt"));
        (
            dir.to_path_buf(),
            if beside.is_file() { beside } else { up },
        )
    };
    if !poses_file.is_file() {
        return Err(layout(&poses_file, "missing: the sequence's poses".into()));
    }
    let camera = match &options.camera {
        Some(c) => c.clone(),
        None => ["image_0", "image_2"]
            .into_iter()
            .find(|c| sequence_dir.join(c).is_dir())
            .unwrap_or("image_0")
            .to_string(),
    };
    let image_dir = sequence_dir.join(&camera);
    let times_file = sequence_dir.join("times.txt");
    let times: Vec<f64> = lines(&times_file)?
        .into_iter()
        .map(|(line, f)| numbers(&times_file, line, &f, 1, "seconds").map(|v| v[0]))
        .collect::<Result<_, _>>()?;
    let mut poses = Vec::new();
    for (line, fields) in lines(&poses_file)? {
        let v = numbers(&poses_file, line, &fields, 12, "a 3x4 [R|t], row by row")?;
        let rotation = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
        poses.push(Pose {
            t: Vector3::new(v[3], v[7], v[11]),
            r: UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&rotation)),
        });
    }
    let files = image_files(&image_dir)?;
    if files.len() != times.len() || poses.len() != times.len() {
        return Err(layout(
            &sequence_dir,
            format!(
                "{} images in {camera}/, {} times in times.txt, {} poses in {}: KITTI gives one of each per frame",
                files.len(),
                times.len(),
                poses.len(),
                poses_file.display()
            ),
        ));
    }
    Ok(Listing {
        images: times.iter().copied().zip(files).collect(),
        poses: times
            .iter()
            .zip(poses)
            .map(|(&time, pose)| TimedPose { time, pose })
            .collect(),
        image_source: image_dir.display().to_string(),
        pose_source: poses_file.display().to_string(),
    })
}

/// The PNG and JPEG files of a folder, by name.
fn image_files(dir: &Path) -> Result<Vec<PathBuf>, RecordingError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(RecordingError::io(dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            matches!(
                p.extension()
                    .and_then(|e| e.to_str())
                    .map(str::to_ascii_lowercase)
                    .as_deref(),
                Some("png" | "jpg" | "jpeg")
            )
        })
        .collect();
    files.sort();
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_line_is_named_by_file_and_number() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("rgb.txt"), "# rgb\n0.0 rgb/0.png\n").unwrap();
        std::fs::write(
            dir.path().join("groundtruth.txt"),
            "# truth\n0.0 0 0 0 0 0 0 1\n0.1 0 0 zero 0 0 0 1\n",
        )
        .unwrap();
        let err = tum(dir.path()).err().unwrap().to_string();
        assert!(err.contains("groundtruth.txt, line 3"), "{err}");
        assert!(err.contains("\"zero\" is not a number"), "{err}");
    }

    #[test]
    fn kitti_counts_must_agree() {
        let dir = tempfile::tempdir().unwrap();
        let seq = dir.path().join("sequences/07");
        std::fs::create_dir_all(seq.join("image_0")).unwrap();
        std::fs::create_dir_all(dir.path().join("poses")).unwrap();
        std::fs::write(seq.join("times.txt"), "0.0\n0.1\n").unwrap();
        std::fs::write(seq.join("image_0/000000.png"), b"").unwrap();
        std::fs::write(
            dir.path().join("poses/07.txt"),
            "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n",
        )
        .unwrap();
        let err = kitti(dir.path(), &Options::default())
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("1 images in image_0/, 2 times"), "{err}");
    }

    #[test]
    fn kitti_rotations_become_quaternions() {
        let dir = tempfile::tempdir().unwrap();
        let seq = dir.path().join("sequences/00");
        std::fs::create_dir_all(seq.join("image_0")).unwrap();
        std::fs::create_dir_all(dir.path().join("poses")).unwrap();
        std::fs::write(seq.join("times.txt"), "0.5\n").unwrap();
        std::fs::write(seq.join("image_0/000000.png"), b"").unwrap();
        // 90° about z, at (1, 2, 3).
        std::fs::write(
            dir.path().join("poses/00.txt"),
            "0 -1 0 1 1 0 0 2 0 0 1 3\n",
        )
        .unwrap();
        let listing = kitti(dir.path(), &Options::default()).unwrap();
        let p = listing.poses[0];
        assert_eq!(p.time, 0.5);
        assert_eq!(p.pose.t, Vector3::new(1.0, 2.0, 3.0));
        let expected = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        assert!(p.pose.r.angle_to(&expected) < 1e-9);
    }
}
