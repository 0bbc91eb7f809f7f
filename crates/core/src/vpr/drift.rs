//! The drift envelope: a candidate of the query's own map farther from
//! the query than the map's drift can explain is a look-alike, not a
//! revisit.
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
//! as they are now, [`crate::index::Index::track_paths`]), the candidate
//! is left out when
//!
//! `d > max_drift_ratio · path + radius`
//!
//! where `radius` is the verdicts' same-place radius (`radius_steps` map
//! spacings, [`crate::vpr::feedback`]). Both terms scale with the map, so
//! the rule is free of scale: a monocular map in arbitrary units is judged
//! as a metric one. The radius also covers the short paths: over the first
//! metres of a map `d ≤ path` always (a straight line is the shortest
//! path), and a candidate a few keyframes back is within the radius.
//! Because `d ≤ path` for any poses, `max_drift_ratio = 1` never leaves
//! anything out: that is its off value. Keyframes without usable poses
//! (every pose at the origin, as image-only clients send them) have
//! `d = 0` and are always kept; queries without a stored keyframe carry
//! no place and keep every candidate. Candidates of other maps are never
//! touched: the path between two maps is unknown until SLAM merges them.

use serde::Serialize;

/// The setting at which the envelope never leaves anything out.
pub const OFF_RATIO: f64 = 1.0;

/// What the envelope found for one candidate of the query's map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DriftEvidence {
    /// `d`, the distance between the two stored positions (map units).
    pub distance: f64,
    /// The path along the map's track between the two keyframes.
    pub path: f64,
    /// `max_drift_ratio · path + radius`: the farthest a revisit may lie.
    pub allowance: f64,
}

impl DriftEvidence {
    /// Measures a candidate `distance` from the query after `path`, with
    /// the map's same-place `radius`, against `max_ratio`.
    pub fn new(distance: f64, path: f64, radius: f64, max_ratio: f64) -> DriftEvidence {
        DriftEvidence {
            distance,
            path,
            allowance: max_ratio * path + radius,
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

    /// Whether the candidate lies farther than the map's drift explains.
    pub fn beyond(&self) -> bool {
        self.distance > self.allowance
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A look-alike 40 m away after 210 m of path lies 19 % of the path
    /// away: beyond 10 % of the path plus a 4.5 m radius (25.5 m).
    #[test]
    fn a_look_alike_40_m_away_after_210_m_is_beyond() {
        let e = DriftEvidence::new(40.0, 210.0, 4.5, 0.1);
        assert!((e.ratio() - 40.0 / 210.0).abs() < 1e-12);
        assert!((e.allowance - 25.5).abs() < 1e-12);
        assert!(e.beyond());
    }

    /// A true revisit after a 400 m lap whose poses drifted by 5 % of it
    /// (20 m) plus 3 m between the two views: 23 m within 44.5 m.
    #[test]
    fn a_revisit_after_a_400_m_lap_with_5_percent_drift_is_within() {
        let e = DriftEvidence::new(23.0, 400.0, 4.5, 0.1);
        assert!(!e.beyond());
        assert!((e.ratio() - 0.0575).abs() < 1e-12);
    }

    /// The rule is free of scale: the same map in units 37 times smaller
    /// (radius and all) gives the same decisions and ratios.
    #[test]
    fn a_map_scaled_down_is_judged_alike() {
        for (d, path) in [(40.0, 210.0), (23.0, 400.0), (5.0, 6.0), (25.5, 210.0)] {
            let metric = DriftEvidence::new(d, path, 4.5, 0.1);
            let k = 1.0 / 37.0;
            let scaled = DriftEvidence::new(d * k, path * k, 4.5 * k, 0.1);
            assert_eq!(metric.beyond(), scaled.beyond(), "{d} m after {path} m");
            assert!((metric.ratio() - scaled.ratio()).abs() < 1e-12);
        }
    }

    /// Over a short path the radius keeps the track's own recent
    /// keyframes; at the off value nothing is beyond; poses at the
    /// origin are never beyond.
    #[test]
    fn short_paths_the_off_value_and_missing_poses_keep_the_candidate() {
        assert!(!DriftEvidence::new(4.4, 4.5, 4.5, 0.1).beyond());
        for (d, path) in [(40.0, 40.0), (1e6, 1e6), (3.0, 3.0)] {
            assert!(!DriftEvidence::new(d, path, 0.0, OFF_RATIO).beyond());
        }
        let origin = DriftEvidence::new(0.0, 0.0, 0.0, 0.1);
        assert!(!origin.beyond());
        assert_eq!(origin.ratio(), 0.0);
    }
}
