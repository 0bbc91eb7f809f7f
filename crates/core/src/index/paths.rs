//! The length of a map's track between two of its keyframes: the path the
//! drift envelope ([`crate::vpr::drift`]) measures a candidate's distance
//! against, and the steps the map's keyframe spacing is the median of.
//!
//! A map's track is its keyframes in keyframe-id order (ORB-SLAM3 numbers
//! keyframes as it makes them); the path between two of them is the sum of
//! the distances between consecutive stored positions from one to the
//! other, read from the poses as they are now, so a pose update after a
//! loop correction changes it at once. An erased or culled keyframe leaves
//! the track, and the path runs straight from its predecessor to its
//! successor: the chain stays whole, a little shorter.
//!
//! Walking a long map's track for every query cost more than the query's
//! scan of it (2.7 ms a query over one map of 40 000 keyframes), so each
//! map keeps its track as a [`TrackPath`]: the keyframe ids in order, the
//! path driven to each and the step into each, built when a query first
//! needs it. A change to keyframe `k` (inserted, erased, moved, its pose
//! updated) only shortens it to the keyframes before `k`, whose path it
//! cannot change; the next query extends it over the rest. A SLAM system
//! appends keyframes and corrects the last few poses, so a query walks
//! those few, and a loop correction that moves the whole map costs one
//! walk.

use std::sync::PoisonError;

use crate::vpr::feedback::squared_distance;

use super::table::{Index, MapKey, TrackPath};

impl Index {
    /// Shortens `map`'s kept path to the keyframes before `id` (keyframe
    /// `id` was inserted, erased, moved or its pose changed); drops it
    /// when the map has no track left.
    pub(super) fn forget_path_from(&mut self, map: &MapKey, id: u64) {
        let paths = self.paths.get_mut().unwrap_or_else(PoisonError::into_inner);
        if !self.tracks.contains_key(map) {
            paths.remove(map);
        } else if let Some(path) = paths.get_mut(map) {
            path.keep_before(id);
        }
    }

    /// Runs `read` on `map`'s whole track path, extending the kept prefix
    /// over the keyframes after it first; `None` for an unknown map.
    pub(super) fn track_path<T>(
        &self,
        map: &MapKey,
        read: impl FnOnce(&TrackPath) -> T,
    ) -> Option<T> {
        let track = self.tracks.get(map)?;
        let mut paths = self.paths.lock().unwrap_or_else(PoisonError::into_inner);
        let path = paths.entry(map.clone()).or_default();
        if path.ids.len() < track.len() {
            let position = |id: &u64| self.rows[track[id]].pose.translation;
            let mut previous = path.ids.last().map(position);
            let mut walked = path.along.last().copied().unwrap_or(0.0);
            let rest = match path.ids.last() {
                Some(&last) => track.range(last + 1..),
                None => track.range(..),
            };
            for (&id, &row) in rest {
                let here = self.rows[row].pose.translation;
                let step = previous.map_or(0.0, |p| squared_distance(p, here).sqrt());
                walked += step;
                previous = Some(here);
                path.ids.push(id);
                path.along.push(walked);
                path.steps.push(step);
            }
        }
        Some(read(path))
    }

    /// The path along the track of `query_row`'s map between it and each
    /// of `rows`: `Some(length)` for a row of the same map, `None` for a
    /// row of another map.
    pub fn track_paths(&self, query_row: usize, rows: &[usize]) -> Vec<Option<f64>> {
        let query = &self.rows[query_row];
        self.track_path(&query.map_key(), |path| {
            let at_query = path.at(query.key.keyframe_id).unwrap_or(0.0);
            rows.iter()
                .map(|&r| {
                    let candidate = &self.rows[r];
                    let at = path.at(candidate.key.keyframe_id);
                    at.filter(|_| candidate.same_map(query))
                        .map(|at| (at - at_query).abs())
                })
                .collect()
        })
        .unwrap_or_else(|| vec![None; rows.len()])
    }
}
