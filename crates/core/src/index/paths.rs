//! The length of a map's track between two of its keyframes: the path the
//! drift envelope ([`crate::vpr::drift`]) measures a candidate's distance
//! against.
//!
//! A map's track is its keyframes in keyframe-id order (ORB-SLAM3 numbers
//! keyframes as it makes them); the path between two of them is the sum of
//! the distances between consecutive stored positions from one to the
//! other, read from the poses as they are now, so a pose update after a
//! loop correction changes it at once. An erased or culled keyframe leaves
//! the track, and the path runs straight from its predecessor to its
//! successor: the chain stays whole, a little shorter. Nothing is cached:
//! one query walks the track once, from the earliest of its keyframes to
//! the latest, a few flops per keyframe, far less than the scan of the
//! same rows.

use std::collections::{HashMap, HashSet};

use crate::vpr::feedback::squared_distance;

use super::table::Index;

impl Index {
    /// The path along the track of `query_row`'s map between it and each
    /// of `rows`: `Some(length)` for a row of the same map, `None` for a
    /// row of another map. One walk over the track between the earliest
    /// and the latest of them.
    pub fn track_paths(&self, query_row: usize, rows: &[usize]) -> Vec<Option<f64>> {
        let query = &self.rows[query_row];
        let same_map: Vec<bool> = rows.iter().map(|&r| self.rows[r].same_map(query)).collect();
        let wanted: HashSet<u64> = rows
            .iter()
            .zip(&same_map)
            .filter(|(_, &same)| same)
            .map(|(&r, _)| self.rows[r].key.keyframe_id)
            .chain([query.key.keyframe_id])
            .collect();
        let first = wanted.iter().min().copied().unwrap_or_default();
        let last = wanted.iter().max().copied().unwrap_or_default();
        let Some(track) = self.tracks.get(&query.map_key()) else {
            return vec![None; rows.len()];
        };
        let mut along: HashMap<u64, f64> = HashMap::with_capacity(wanted.len());
        let mut walked = 0.0;
        let mut previous: Option<[f64; 3]> = None;
        for (&id, &row) in track.range(first..=last) {
            let position = self.rows[row].pose.translation;
            if let Some(p) = previous {
                walked += squared_distance(p, position).sqrt();
            }
            previous = Some(position);
            if wanted.contains(&id) {
                along.insert(id, walked);
            }
        }
        let at_query = along.get(&query.key.keyframe_id).copied().unwrap_or(0.0);
        rows.iter()
            .zip(same_map)
            .map(|(&r, same)| {
                let at = along.get(&self.rows[r].key.keyframe_id).copied();
                at.filter(|_| same).map(|at| (at - at_query).abs())
            })
            .collect()
    }
}
