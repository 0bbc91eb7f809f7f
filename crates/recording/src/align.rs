//! Images meet poses: the pose at an image's time, and the images that
//! become keyframes.
//!
//! Cameras and pose sources tick at their own rates, so an image's pose is
//! interpolated between the poses on either side of it (position linearly,
//! orientation by slerp) when both lie within the tolerance, or is the
//! nearest pose when only that one does; an image with neither is left
//! out and counted. Keyframes then follow SLAM's habit: a new one when the
//! camera has moved far enough, turned far enough, or enough time has
//! passed since the last, so a robot standing still adds nothing.

use crate::error::RecordingError;
use crate::pose::{Pose, TimedPose};

/// When an image becomes a keyframe: the first always, then each image
/// that is at least `min_distance_m` from the last keyframe, or turned at
/// least `min_angle_deg` from it, or `max_interval_s` after it. A rule of
/// 0 is off; all three off keeps every image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeRule {
    /// Metres (0: off).
    pub min_distance_m: f64,
    /// Degrees (0: off).
    pub min_angle_deg: f64,
    /// Seconds (0: off).
    pub max_interval_s: f64,
}

impl Default for KeyframeRule {
    /// 0.5 m or 15°, no time rule.
    fn default() -> Self {
        KeyframeRule {
            min_distance_m: 0.5,
            min_angle_deg: 15.0,
            max_interval_s: 0.0,
        }
    }
}

impl KeyframeRule {
    /// Every image is a keyframe.
    pub fn every_image() -> Self {
        KeyframeRule {
            min_distance_m: 0.0,
            min_angle_deg: 0.0,
            max_interval_s: 0.0,
        }
    }

    fn keeps_all(&self) -> bool {
        self.min_distance_m <= 0.0 && self.min_angle_deg <= 0.0 && self.max_interval_s <= 0.0
    }

    /// Indices of `frames` (time, pose; in time order) that are keyframes.
    pub fn select(&self, frames: &[(f64, Pose)]) -> Vec<usize> {
        if self.keeps_all() {
            return (0..frames.len()).collect();
        }
        let mut kept: Vec<usize> = Vec::new();
        for (i, (time, pose)) in frames.iter().enumerate() {
            let Some(&last) = kept.last() else {
                kept.push(i);
                continue;
            };
            let (last_time, last_pose) = &frames[last];
            let moved = (pose.t - last_pose.t).norm();
            let turned = last_pose.r.angle_to(&pose.r).to_degrees();
            if (self.min_distance_m > 0.0 && moved >= self.min_distance_m)
                || (self.min_angle_deg > 0.0 && turned >= self.min_angle_deg)
                || (self.max_interval_s > 0.0 && time - last_time >= self.max_interval_s)
            {
                kept.push(i);
            }
        }
        kept
    }
}

/// The pose at `time` from `poses` (sorted by time): interpolated between
/// the poses either side when both are within `tolerance` seconds, else
/// the nearest within `tolerance`, else `None`.
pub fn pose_at(poses: &[TimedPose], time: f64, tolerance: f64) -> Option<Pose> {
    let after = poses.partition_point(|p| p.time < time);
    let next = poses.get(after);
    let prev = after.checked_sub(1).map(|i| &poses[i]);
    let near = |p: &&TimedPose| (p.time - time).abs() <= tolerance;
    match (prev.filter(near), next.filter(near)) {
        (Some(a), Some(b)) if b.time > a.time => {
            let s = (time - a.time) / (b.time - a.time);
            Some(a.pose.interpolate(&b.pose, s))
        }
        (_, Some(b)) if b.time == time => Some(b.pose),
        (Some(a), Some(b)) => Some(if time - a.time <= b.time - time {
            a.pose
        } else {
            b.pose
        }),
        (Some(a), None) => Some(a.pose),
        (None, Some(b)) => Some(b.pose),
        (None, None) => None,
    }
}

/// Sorts poses by time (a stable sort: equal times keep their order).
pub fn sort_poses(poses: &mut [TimedPose]) {
    poses.sort_by(|a, b| a.time.total_cmp(&b.time));
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    fn pose(x: f64, yaw_deg: f64) -> Pose {
        Pose {
            t: Vector3::new(x, 0.0, 0.0),
            r: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()),
        }
    }

    fn timed(time: f64, x: f64, yaw: f64) -> TimedPose {
        TimedPose {
            time,
            pose: pose(x, yaw),
        }
    }

    #[test]
    fn a_pose_between_two_is_interpolated() {
        let poses = [timed(1.0, 0.0, 0.0), timed(2.0, 10.0, 90.0)];
        let p = pose_at(&poses, 1.25, 1.0).unwrap();
        assert!((p.t.x - 2.5).abs() < 1e-12);
        assert!((p.r.angle().to_degrees() - 22.5).abs() < 1e-9);
        // An exact time gives that pose.
        assert_eq!(pose_at(&poses, 2.0, 0.0).unwrap(), poses[1].pose);
    }

    #[test]
    fn only_poses_within_the_tolerance_count() {
        let poses = [timed(1.0, 0.0, 0.0), timed(2.0, 10.0, 0.0)];
        // 1.25 is 0.25 from the first and 0.75 from the second: the first.
        assert_eq!(pose_at(&poses, 1.25, 0.3).unwrap(), poses[0].pose);
        assert_eq!(pose_at(&poses, 1.5, 0.3), None);
        assert_eq!(pose_at(&poses, 2.1, 0.2).unwrap(), poses[1].pose);
        assert_eq!(pose_at(&poses, 0.5, 0.2), None);
        assert_eq!(pose_at(&[], 0.5, 10.0), None);
    }

    #[test]
    fn images_without_poses_are_counted_and_none_at_all_is_an_error() {
        let poses = [timed(10.0, 0.0, 0.0), timed(11.0, 1.0, 0.0)];
        let rule = KeyframeRule::every_image();
        let p = plan(
            &[10.0, 10.5, 11.0, 30.0],
            &poses,
            0.6,
            &rule,
            "/cam",
            "/odom",
        )
        .unwrap();
        assert_eq!((p.images, p.without_pose, p.keyframes.len()), (4, 1, 3));
        assert_eq!(p.keyframes[1].0, 1);
        assert!((p.keyframes[1].2.t.x - 0.5).abs() < 1e-12);
        let err = plan(&[1.0, 2.0], &poses, 0.1, &rule, "/cam", "/odom")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("no image from /cam has a pose from /odom within 0.1 s"),
            "{err}"
        );
        assert!(
            err.contains("2 images at 1.000 .. 2.000 s, 2 poses at 10.000 .. 11.000 s"),
            "{err}"
        );
    }

    #[test]
    fn keyframes_follow_distance_angle_and_time() {
        let frames: Vec<(f64, Pose)> = [
            (0.0, 0.0, 0.0),
            (0.1, 0.2, 0.0),  // 0.2 m: no
            (0.2, 0.6, 0.0),  // 0.6 m from the first: yes
            (0.3, 0.7, 20.0), // turned 20°: yes
            (0.4, 0.7, 20.0), // still: no
            (5.0, 0.7, 20.0), // still, but 4.7 s later
        ]
        .iter()
        .map(|&(t, x, yaw)| (t, pose(x, yaw)))
        .collect();
        let rule = KeyframeRule {
            min_distance_m: 0.5,
            min_angle_deg: 15.0,
            max_interval_s: 0.0,
        };
        assert_eq!(rule.select(&frames), vec![0, 2, 3]);
        let timed = KeyframeRule {
            max_interval_s: 2.0,
            ..rule
        };
        assert_eq!(timed.select(&frames), vec![0, 2, 3, 5]);
        assert_eq!(KeyframeRule::every_image().select(&frames).len(), 6);
    }
}

/// The images that become keyframes, with their poses.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// `(image index, time, pose)` of each keyframe, in time order.
    pub keyframes: Vec<(usize, f64, Pose)>,
    /// Images read.
    pub images: usize,
    /// Images without a pose within the tolerance.
    pub without_pose: usize,
}

/// Gives each image (by its time; index = position in `times`) its pose
/// and picks the keyframes. Fails when no image has a pose.
pub fn plan(
    times: &[f64],
    poses: &[TimedPose],
    tolerance: f64,
    rule: &KeyframeRule,
    image_source: &str,
    pose_source: &str,
) -> Result<Plan, RecordingError> {
    let mut order: Vec<usize> = (0..times.len()).collect();
    order.sort_by(|&a, &b| times[a].total_cmp(&times[b]).then(a.cmp(&b)));
    let posed: Vec<(usize, f64, Pose)> = order
        .iter()
        .filter_map(|&i| pose_at(poses, times[i], tolerance).map(|p| (i, times[i], p)))
        .collect();
    if posed.is_empty() {
        let span = |v: &mut dyn Iterator<Item = f64>| {
            let (lo, hi) = v.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), t| {
                (lo.min(t), hi.max(t))
            });
            if lo.is_finite() {
                format!("{lo:.3} .. {hi:.3} s")
            } else {
                "none".to_string()
            }
        };
        return Err(RecordingError::NoPose {
            images: image_source.into(),
            poses: pose_source.into(),
            tolerance,
            detail: format!(
                "{} images at {}, {} poses at {}",
                times.len(),
                span(&mut times.iter().copied()),
                poses.len(),
                span(&mut poses.iter().map(|p| p.time))
            ),
        });
    }
    let frames: Vec<(f64, Pose)> = posed.iter().map(|&(_, t, p)| (t, p)).collect();
    let keyframes = rule.select(&frames).into_iter().map(|k| posed[k]).collect();
    Ok(Plan {
        keyframes,
        images: times.len(),
        without_pose: times.len() - posed.len(),
    })
}
