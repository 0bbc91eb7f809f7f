//! Changes to the index: keyframes inserted, replaced, erased and moved.
//!
//! Every change keeps the row-aligned tables dense (an erased row is
//! filled by the last one), the predecessor links of the temporal tracks
//! right, the text document frequencies counted, and drops what was cached
//! about the maps and verdicts it touched.

use std::collections::HashSet;

use crate::engine::matrix::DescriptorMatrix;
use crate::keyframe::{KeyframeKey, ObjectObservation, Pose, SemanticKeyframe};
use crate::row_ids::RowIds;
use crate::vpr::calibration::sample_tag;
use crate::vpr::text::normalize;

use super::eligible::SAMPLED_MASK;
use super::table::{Index, RowMeta, NO_ROW};

impl Index {
    /// Stores a keyframe, replacing the one with the same key. Returns true if
    /// one was replaced. The descriptor must have the index's length (the
    /// first keyframe of an empty index fixes it when it is 0).
    pub fn upsert(&mut self, keyframe: SemanticKeyframe) -> bool {
        // A replaced keyframe keeps its verdicts: it is the same keyframe.
        let replaced = self.remove_row(&keyframe.key);
        if self.matrix.dim() == 0 && self.matrix.is_empty() {
            self.matrix = DescriptorMatrix::new(keyframe.features.descriptor.len());
        }
        assert!(
            self.rows.len() < NO_ROW as usize,
            "at most 2³² − 1 keyframes"
        );
        let row = self.matrix.push(&keyframe.features.descriptor);
        self.attach(row, keyframe);
        self.graph_insert(row);
        replaced
    }

    /// Adds everything but the descriptor of the keyframe in matrix row
    /// `row`, which must be the next row (`row == len()`), and links it
    /// into its track.
    pub(super) fn attach(&mut self, row: usize, keyframe: SemanticKeyframe) {
        debug_assert_eq!(row, self.rows.len());
        self.changes += 1;
        self.preds.push(NO_ROW);
        self.tags.push(sample_tag(&keyframe.key));
        self.appearance.push(&keyframe.features.appearance);
        for text in distinct_texts(&keyframe.features.objects) {
            *self.text_df.entry(text).or_insert(0) += 1;
        }
        let (robot, session) = self
            .interner
            .intern(&keyframe.key.robot_id, &keyframe.key.session_id);
        self.by_key.insert(keyframe.key.clone(), row);
        self.ids.push(RowIds {
            robot,
            session,
            map_id: keyframe.map_id,
            frame_id: keyframe.frame_id,
            keyframe_id: keyframe.key.keyframe_id,
        });
        self.rows.push(RowMeta {
            key: keyframe.key,
            frame_id: keyframe.frame_id,
            timestamp: keyframe.timestamp,
            map_id: keyframe.map_id,
            pose: keyframe.pose,
            scene: keyframe.features.scene,
            objects: keyframe.features.objects,
        });
        self.link(row);
    }

    /// Removes a keyframe and every verdict naming it; returns true if it
    /// was stored.
    pub fn remove(&mut self, key: &KeyframeKey) -> bool {
        if self.verdicts.forget(key) > 0 {
            self.forget_operating_point();
        }
        let removed = self.remove_row(key);
        if removed {
            *self.erasures.entry(key.session()).or_insert(0) += 1;
        }
        removed
    }

    /// How many times row numbers have stopped naming the keyframes they
    /// named: every removal (the last row fills the hole, or the last row
    /// goes) and every grouping counts once; appending a row keeps every
    /// number. A reader that keeps row numbers across releases of the
    /// index's lock (a pass over a large store in pieces) checks that this
    /// did not change.
    pub fn renumberings(&self) -> u64 {
        self.renumberings
    }

    /// Removes a keyframe's row, leaving its verdicts.
    fn remove_row(&mut self, key: &KeyframeKey) -> bool {
        let Some(row) = self.by_key.remove(key) else {
            return false;
        };
        self.changes += 1;
        self.renumberings += 1;
        self.graph_remove(row);
        self.unlink(row);
        for text in distinct_texts(&self.rows[row].objects) {
            if let Some(count) = self.text_df.get_mut(&text) {
                *count -= 1;
                if *count == 0 {
                    self.text_df.remove(&text);
                }
            }
        }
        // Move the last row into the hole and repoint everything that
        // referred to the last row.
        let last = self.rows.len() - 1;
        self.matrix.swap_remove(row);
        self.appearance.swap_remove(row);
        self.rows.swap_remove(row);
        self.ids.swap_remove(row);
        self.preds.swap_remove(row);
        self.tags.swap_remove(row);
        // The tail's last row fills the hole (or, without a tail, the
        // grouped rows' last one): the grouped rows end where they did, or
        // at the new end.
        self.grouped = self.grouped.min(last);
        if row != last {
            self.note_displaced(row);
            self.graph_moved(last, row);
            let moved = &self.rows[row];
            self.by_key.insert(moved.key.clone(), row);
            let map = moved.map_key();
            let id = moved.key.keyframe_id;
            let track = self.tracks.get_mut(&map).expect("moved row has a track");
            track.insert(id, row);
            if let Some((_, &next)) = track.range(id + 1..).next() {
                self.set_prev(next, Some(row));
            }
        }
        true
    }

    /// Moves a keyframe to a corrected pose and, optionally, another map.
    /// Returns false if the keyframe is not stored.
    pub fn update_pose(&mut self, key: &KeyframeKey, pose: Pose, map_id: Option<u64>) -> bool {
        let Some(row) = self.row_of(key) else {
            return false;
        };
        let map = self.rows[row].map_key();
        self.forget_spacing(&map);
        self.forget_path_from(&map, key.keyframe_id);
        self.changes += 1;
        self.rows[row].pose = pose;
        if let Some(map_id) = map_id {
            if map_id != self.rows[row].map_id {
                self.unlink(row);
                self.rows[row].map_id = map_id;
                self.ids[row].map_id = map_id;
                self.link(row);
                self.note_displaced(row);
            }
        }
        true
    }

    /// Inserts `row` into its map's track and fixes the predecessor links of
    /// it and of its successor.
    fn link(&mut self, row: usize) {
        let map = self.rows[row].map_key();
        let id = self.rows[row].key.keyframe_id;
        self.forget_spacing(&map);
        self.forget_path_from(&map, id);
        let tag = self.tags[row];
        if tag & SAMPLED_MASK == 0 {
            self.sampled.entry(map.clone()).or_default().insert(id, tag);
        }
        let track = self.tracks.entry(map).or_default();
        track.insert(id, row);
        let prev = track.range(..id).next_back().map(|(_, &r)| r);
        let next = track.range(id + 1..).next().map(|(_, &r)| r);
        self.set_prev(row, prev);
        if let Some(next) = next {
            self.set_prev(next, Some(row));
        }
    }

    /// Takes `row` out of its map's track, joining its neighbours.
    fn unlink(&mut self, row: usize) {
        let map = self.rows[row].map_key();
        let id = self.rows[row].key.keyframe_id;
        self.forget_spacing(&map);
        let prev = self.prev(row);
        let Some(track) = self.tracks.get_mut(&map) else {
            return;
        };
        track.remove(&id);
        let next = track.range(id + 1..).next().map(|(_, &r)| r);
        if track.is_empty() {
            self.tracks.remove(&map);
        }
        if let Some(sampled) = self.sampled.get_mut(&map) {
            sampled.remove(&id);
            if sampled.is_empty() {
                self.sampled.remove(&map);
            }
        }
        self.forget_path_from(&map, id);
        if let Some(next) = next {
            self.set_prev(next, prev);
        }
        self.set_prev(row, None);
    }

    fn set_prev(&mut self, row: usize, prev: Option<usize>) {
        // Rows fit in u32: `upsert` stops short of NO_ROW.
        self.preds[row] = prev.map_or(NO_ROW, |p| p as u32);
    }
}

/// The distinct normalised strings read on a keyframe's objects: each counts
/// once per keyframe in the document frequency.
pub(super) fn distinct_texts(objects: &[ObjectObservation]) -> HashSet<String> {
    objects
        .iter()
        .flat_map(|o| o.texts.iter())
        .map(|t| normalize(&t.text))
        .filter(|t| !t.is_empty())
        .collect()
}
