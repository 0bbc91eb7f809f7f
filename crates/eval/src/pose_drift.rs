//! Poses as a drifting odometry would send them: the replay's stand-in for
//! SLAM's own estimate, since ground-truth poses make any pose rule look
//! perfect.
//!
//! The drive is integrated again step by step from the data set's poses:
//! each step's motion (the vector between two consecutive positions) is
//! turned by the accumulated heading error `ψ` (about the world's z axis,
//! up in the data sets' poses) and stretched by the accumulated scale
//! error `e^σ`, and each camera's orientation is turned by `ψ` as well.
//! `ψ` and `σ` are random walks over the distance driven, with a variance
//! of `q` per metre each, seeded. The position error they make between
//! two keyframes grows as `path^1.5` (the integral of a Brownian motion):
//! on a straight stretch its mean square is `2q · path³/3`. A constant
//! error of heading or scale moves a closed loop alike and cannot separate
//! a revisit from its first visit; only its change along the path does,
//! and around a closed square loop the mean square is 0.156 of the
//! straight stretch's. `q = 9.6 ρ² / 200 m` makes the error of a revisit
//! after a square loop of 200 m `ρ` of that loop (rms): with
//! `--replay-pose-drift 0.03` a robot back at its start after a town
//! block's lap finds it about 6 m off, 3 % of the path, less after shorter
//! loops and more after longer ones, as visual odometry's drift is.

use humem_core::keyframe::Pose;
use humem_core::synthetic::Rng;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// The loop, in metres, after which a revisit is `ρ` of it off.
pub const DRIFT_REFERENCE_M: f64 = 200.0;

/// `q · 200 m / ρ²`: the variance per metre of the heading and scale
/// walks that makes a square loop's revisit error `ρ` of it (see the
/// module doc).
const WALK_VARIANCE: f64 = 9.6;

/// `poses` (consecutive keyframes of one drive) as an odometry drifting
/// by `rate` of the path would have them; the first pose is kept. `rate`
/// 0 returns them unchanged.
pub fn drifted(poses: &[Pose], rate: f64, seed: u64) -> Vec<Pose> {
    if rate == 0.0 || poses.is_empty() {
        return poses.to_vec();
    }
    let per_root_metre = (WALK_VARIANCE * rate * rate / DRIFT_REFERENCE_M).sqrt();
    let mut rng = Rng::new(seed);
    let (mut heading, mut log_scale) = (0.0f64, 0.0f64);
    let mut out = Vec::with_capacity(poses.len());
    out.push(poses[0]);
    for pair in poses.windows(2) {
        let step = Vector3::from(pair[1].translation) - Vector3::from(pair[0].translation);
        let walk = per_root_metre * step.norm().sqrt();
        heading += walk * normal(&mut rng);
        log_scale += walk * normal(&mut rng);
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), heading);
        let previous: Vector3<f64> =
            Vector3::from(out.last().map_or([0.0; 3], |p: &Pose| p.translation));
        let position = previous + turn * step * log_scale.exp();
        let [w, x, y, z] = pair[1].rotation;
        let orientation = turn * UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
        let q = orientation.quaternion();
        out.push(Pose {
            translation: position.into(),
            rotation: [q.w, q.i, q.j, q.k],
        });
    }
    out
}

/// A standard normal draw (Box–Muller).
fn normal(rng: &mut Rng) -> f64 {
    let uniform = |rng: &mut Rng| ((rng.next() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    let (a, b) = (uniform(rng), uniform(rng));
    (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square loop of 200 m (sides of 50 m) in 1 m steps, driven `laps`
    /// times.
    fn square_laps(laps: usize) -> Vec<Pose> {
        let mut poses = Vec::new();
        for i in 0..laps * 200 {
            let s = (i % 200) as f64;
            let (x, y) = match (s / 50.0) as usize {
                0 => (s, 0.0),
                1 => (50.0, s - 50.0),
                2 => (150.0 - s, 50.0),
                _ => (0.0, 200.0 - s),
            };
            poses.push(Pose {
                translation: [x, y, 0.0],
                ..Pose::default()
            });
        }
        poses
    }

    /// Rate 0 changes nothing; a seed gives the same poses every time.
    #[test]
    fn no_drift_is_the_drive_itself_and_a_seed_repeats() {
        let poses = square_laps(1);
        assert_eq!(drifted(&poses, 0.0, 7), poses);
        assert_eq!(drifted(&poses, 0.03, 7), drifted(&poses, 0.03, 7));
        assert_ne!(drifted(&poses, 0.03, 7), drifted(&poses, 0.03, 8));
    }

    /// Back at the start after a 200 m lap, the drifted revisit lies about
    /// `ρ · 200 m` (rms over seeds) from where the map put the start.
    #[test]
    fn a_revisit_after_the_reference_loop_is_off_by_the_rate_of_it() {
        let poses = square_laps(2);
        let rate = 0.03;
        let seeds = 400;
        let mean_square: f64 = (0..seeds)
            .map(|seed| {
                let d = drifted(&poses, rate, seed);
                let (a, b) = (
                    Vector3::from(d[0].translation),
                    Vector3::from(d[200].translation),
                );
                (a - b).norm_squared()
            })
            .sum::<f64>()
            / seeds as f64;
        let rms = mean_square.sqrt();
        assert!(
            (rms / (rate * 200.0) - 1.0).abs() < 0.25,
            "rms error {rms:.2} m against {:.2} m",
            rate * 200.0
        );
    }
}
