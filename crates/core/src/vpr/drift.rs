//! The drift envelope: a candidate of the query's own map farther from
//! the query than the map's drift can explain is likely a look-alike, not
//! a revisit, and loses score.
//!
//! SLAM's keyframe poses drift, but by a few per cent of the path driven
//! between two keyframes, not more: a place revisited after a lap of
//! `path` metres lies within `drift · path` of where the map puts its
//! first visit, plus the distance at which two views still show the same
//! place. A look-alike block elsewhere in the town lies much farther: in
//! the rendered town loop the first-visit look-alikes that reached the
//! operating point were 36–43 m from the query after 210–218 m of path
//! (17–20 % of it), while every true pair of the loop lies within 2.6 %
//! of its path (ground-truth poses).
//!
//! So for a candidate `c` of the query `q`'s map, with `d = ‖p_q − p_c‖`
//! and `path` the length of the map's track between them (the sum of the
//! distances between consecutive keyframes by keyframe id, with the poses
//! as they are now, [`crate::index::Index::track_paths`]), the envelope
//! allows
//!
//! `allowance = b · path + radius`, `b = max_drift_ratio`
//!
//! where `radius` is the verdicts' same-place radius (`radius_steps` map
//! spacings, [`crate::vpr::feedback`]). A candidate beyond it has its score
//! lowered, by nothing at the allowance rising linearly to [`PENALTY`] at
//! twice the ratio (`2b · path + radius`) and beyond:
//!
//! `penalty = PENALTY · clip((d − allowance) / (b · path), 0, 1)`
//!
//! Lowered, not left out: a monocular map drifts in scale, and before its
//! first loop correction a true revisit can lie a quarter of the path away
//! (ORB-SLAM3's own trajectories of the town loop: `r` up to 0.26 for the
//! first return to the start). Those revisits score well above the
//! threshold and survive a lowered score; the look-alikes that reach the
//! operating point on a first visit score just above it and do not.
//!
//! Both terms scale with the map, so the rule is free of scale: a
//! monocular map in arbitrary units is judged as a metric one. The radius
//! also covers the short paths: over the first metres of a map `d ≤ path`
//! always (a straight line is the shortest path), and a candidate a few
//! keyframes back is within the radius. Because `d ≤ path` for any poses,
//! `max_drift_ratio = 1` never lowers anything: that is its off value.
//! Keyframes without usable poses (every pose at the origin, as image-only
//! clients send them) have `d = 0` and are never lowered; queries without
//! a stored keyframe carry no place and keep every score. Candidates of
//! other maps are never touched: the path between two maps is unknown
//! until SLAM merges them.

use serde::Serialize;

/// The setting at which the envelope never lowers anything.
pub const OFF_RATIO: f64 = 1.0;

/// The most the envelope takes from a score, reached at twice the
/// allowed ratio: enough to take a look-alike that scores just above the
/// operating point (0.36) below it, little against a revisit that scores
/// 0.5 or more.
pub const PENALTY: f32 = 0.1;

/// What the envelope found for one candidate of the query's map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DriftEvidence {
    /// `d`, the distance between the two stored positions (map units).
    pub distance: f64,
    /// The path along the map's track between the two keyframes.
    pub path: f64,
    /// `max_drift_ratio · path + radius`: the farthest a revisit lies
    /// without losing score.
    pub allowance: f64,
    /// What the envelope took from the candidate's score, in
    /// `[0, PENALTY]`.
    pub penalty: f32,
}

impl DriftEvidence {
    /// Measures a candidate `distance` from the query after `path`, with
    /// the map's same-place `radius`, against `max_ratio`.
    pub fn new(distance: f64, path: f64, radius: f64, max_ratio: f64) -> DriftEvidence {
        let allowance = max_ratio * path + radius;
        let ramp = max_ratio * path;
        let excess = distance - allowance;
        let share = if excess <= 0.0 {
            0.0
        } else if ramp > 0.0 {
            (excess / ramp).min(1.0)
        } else {
            1.0
        };
        DriftEvidence {
            distance,
            path,
            allowance,
            penalty: PENALTY * share as f32,
        }
    }

    /// `r = d / path`, the share of the path the candidate lies away; 0
    /// where the path is 0 (both at one position).
    pub fn ratio(&self) -> f64 {
        if self.path > 0.0 {
            self.distance / self.path
        } else {
            0.0
        }
    }

    /// Whether the candidate lies farther than the map's drift explains
    /// (its score is lowered).
    pub fn beyond(&self) -> bool {
        self.distance > self.allowance
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() < 1e-6
    }

    /// A look-alike 40 m away after 210 m of path lies 19 % of the path
    /// away: beyond 5 % of the path plus a 4.5 m radius (15 m), and past
    /// twice the ratio (25.5 m): the whole penalty.
    #[test]
    fn a_look_alike_40_m_away_after_210_m_loses_the_whole_penalty() {
        let e = DriftEvidence::new(40.0, 210.0, 4.5, 0.05);
        assert!((e.ratio() - 40.0 / 210.0).abs() < 1e-12);
        assert!((e.allowance - 15.0).abs() < 1e-12);
        assert!(e.beyond());
        assert!(close(e.penalty, PENALTY));
    }

    /// Between the allowance and twice the ratio the penalty rises
    /// linearly: 20 m after 210 m is (20 − 15) / 10.5 of the way.
    #[test]
    fn the_penalty_rises_linearly_to_twice_the_ratio() {
        let e = DriftEvidence::new(20.0, 210.0, 4.5, 0.05);
        assert!(close(e.penalty, PENALTY * (5.0 / 10.5) as f32));
        let at = DriftEvidence::new(15.0, 210.0, 4.5, 0.05);
        assert!(!at.beyond());
        assert_eq!(at.penalty, 0.0);
    }

    /// A true revisit after a 400 m lap whose poses drifted by 5 % of it
    /// (20 m), 3 m between the two views: 23 m within 24.5 m, untouched.
    #[test]
    fn a_revisit_after_a_400_m_lap_with_5_percent_drift_keeps_its_score() {
        let e = DriftEvidence::new(23.0, 400.0, 4.5, 0.05);
        assert!(!e.beyond());
        assert_eq!(e.penalty, 0.0);
        assert!((e.ratio() - 0.0575).abs() < 1e-12);
    }

    /// The rule is free of scale: the same map in units 37 times smaller
    /// (radius and all) gives the same penalties and ratios.
    #[test]
    fn a_map_scaled_down_is_judged_alike() {
        for (d, path) in [(40.0, 210.0), (23.0, 400.0), (5.0, 6.0), (20.0, 210.0)] {
            let metric = DriftEvidence::new(d, path, 4.5, 0.05);
            let k = 1.0 / 37.0;
            let scaled = DriftEvidence::new(d * k, path * k, 4.5 * k, 0.05);
            assert_eq!(metric.beyond(), scaled.beyond(), "{d} m after {path} m");
            assert!(
                close(metric.penalty, scaled.penalty),
                "{d} m after {path} m"
            );
            assert!((metric.ratio() - scaled.ratio()).abs() < 1e-12);
        }
    }

    /// Over a short path the radius keeps the track's own recent
    /// keyframes; at the off value nothing is lowered; poses at the
    /// origin never are.
    #[test]
    fn short_paths_the_off_value_and_missing_poses_keep_the_score() {
        assert_eq!(DriftEvidence::new(4.4, 4.5, 4.5, 0.05).penalty, 0.0);
        for (d, path) in [(40.0, 40.0), (1e6, 1e6), (3.0, 3.0)] {
            let e = DriftEvidence::new(d, path, 0.0, OFF_RATIO);
            assert!(!e.beyond());
            assert_eq!(e.penalty, 0.0);
        }
        let origin = DriftEvidence::new(0.0, 0.0, 0.0, 0.05);
        assert!(!origin.beyond());
        assert_eq!(origin.penalty, 0.0);
        assert_eq!(origin.ratio(), 0.0);
    }
}
