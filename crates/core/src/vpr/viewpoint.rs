//! Views that cannot show the same place: a candidate of the query's own
//! map whose camera was turned far away from the query's.
//!
//! Within one map, SLAM's keyframe poses share a frame, and their
//! orientations stay close to the truth even where the positions drift
//! (monocular scale drift moves positions, not headings): in the ORB-SLAM3
//! harness runs on `town-dev/loop`, the map's relative rotation of every
//! pair proposed to geometry was within 8° of the ground truth's. Two
//! views whose rotations differ by more than a right angle's worth share
//! little of what a perspective camera sees, and a feature-based
//! geometric check cannot verify them. Yet such views across a junction
//! are what a global descriptor confuses: seven of the nine false loop
//! candidates of those runs were 81–96° apart (frame 304 with frames 91
//! and 92, 395 with 0, 397 with 2), and no true one was more than 24°
//! apart.
//!
//! So a candidate of the query's map (same robot, session and map id) is
//! left out when the angle of the rotation between the two camera poses,
//! `θ = 2 acos |⟨q_a, q_b⟩|` (the geodesic distance of the two unit
//! quaternions, whatever axis the body frame calls forward), exceeds
//! `vpr.max_view_change_deg`. Candidates of other maps are never touched:
//! their frames are unrelated until SLAM merges them. A query without a
//! stored pose (an image) has no orientation and keeps every candidate.
//! The default, 60°, is twice the evaluation protocol's 30° for "the same
//! place"; cameras that see all around (fisheye, 360°) set it to 180,
//! which turns the rule off.

use nalgebra::{Quaternion, UnitQuaternion};

use crate::keyframe::Pose;

/// The rule's setting at which it never leaves anything out.
pub const OFF_DEG: f64 = 180.0;

/// Geodesic angle between two orientations: the rotation angle of `a⁻¹b`,
/// in degrees, in `[0, 180]`. `q` and `−q` are the same rotation.
pub fn geodesic_deg(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    let d = a.inverse() * b;
    // 2·atan2(|v|, |w|) is accurate at small angles, where 2·acos(|w|) loses
    // digits; |w| folds q and −q together and keeps the angle ≤ 180°.
    let angle = 2.0 * d.imag().norm().atan2(d.scalar().abs());
    angle.to_degrees().clamp(0.0, 180.0)
}

/// `θ`, [`geodesic_deg`] of the orientations of two stored poses;
/// quaternions are normalised first, and one of zero length (which the
/// API refuses) counts as no rotation.
pub fn rotation_angle_deg(a: &Pose, b: &Pose) -> f64 {
    let unit = |[w, x, y, z]: [f64; 4]| UnitQuaternion::try_new(Quaternion::new(w, x, y, z), 0.0);
    match (unit(a.rotation), unit(b.rotation)) {
        (Some(a), Some(b)) => geodesic_deg(&a, &b),
        _ => 0.0,
    }
}

/// Whether a candidate at `candidate`, in the same map as a query at
/// `query`, is turned further from it than `max_deg` allows (never at
/// [`OFF_DEG`], since no rotation is more than 180°).
pub fn turned_away(max_deg: f64, query: &Pose, candidate: &Pose) -> bool {
    rotation_angle_deg(query, candidate) > max_deg
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera turned by `deg` about the map's z axis.
    fn yawed(deg: f64) -> Pose {
        let h = deg.to_radians() / 2.0;
        Pose {
            translation: [0.0; 3],
            rotation: [h.cos(), 0.0, 0.0, h.sin()],
        }
    }

    #[test]
    fn the_angle_is_that_of_the_rotation_between_the_two() {
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
        assert!(close(rotation_angle_deg(&yawed(0.0), &yawed(0.0)), 0.0));
        assert!(close(rotation_angle_deg(&yawed(10.0), &yawed(100.0)), 90.0));
        assert!(close(rotation_angle_deg(&yawed(-30.0), &yawed(30.0)), 60.0));
        // 350° is 10° the other way round.
        assert!(close(rotation_angle_deg(&yawed(0.0), &yawed(350.0)), 10.0));
        // −q is the same rotation as q; an unnormalised q as well.
        let q = yawed(40.0);
        let minus = Pose {
            rotation: q.rotation.map(|x| -x),
            ..q
        };
        let doubled = Pose {
            rotation: q.rotation.map(|x| 2.0 * x),
            ..q
        };
        assert!(close(rotation_angle_deg(&q, &minus), 0.0));
        assert!(close(rotation_angle_deg(&yawed(0.0), &doubled), 40.0));
        // A pitch of 90° (about x): 90°, whatever axis is forward.
        let h = std::f64::consts::FRAC_PI_4;
        let pitched = Pose {
            translation: [0.0; 3],
            rotation: [h.cos(), h.sin(), 0.0, 0.0],
        };
        assert!(close(rotation_angle_deg(&yawed(0.0), &pitched), 90.0));
    }

    #[test]
    fn only_views_turned_further_than_the_setting_are_left_out() {
        assert!(!turned_away(60.0, &yawed(0.0), &yawed(59.0)));
        assert!(!turned_away(60.0, &yawed(0.0), &yawed(60.0)));
        assert!(turned_away(60.0, &yawed(0.0), &yawed(61.0)));
        assert!(turned_away(60.0, &yawed(0.0), &yawed(180.0)));
        // 180: off.
        assert!(!turned_away(OFF_DEG, &yawed(0.0), &yawed(180.0)));
    }
}
