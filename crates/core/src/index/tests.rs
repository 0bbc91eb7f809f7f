//! The index's invariants, checked against a from-scratch recomputation
//! after inserts, replacements, erasures and moves.

use std::collections::{BTreeMap, HashMap};

use super::table::{Index, MapKey};
use crate::keyframe::{Features, TextObservation};
use crate::keyframe::{KeyframeKey, ObjectObservation, Pose, SemanticKeyframe, SessionKey};
use crate::vpr;
use crate::vpr::memory::KeyframeMemory;

fn kf(session: &str, id: u64, map: u64, text: &str) -> SemanticKeyframe {
    let mut keyframe = kf_of("r", session, id, map);
    keyframe.features.objects[0].texts[0].text = text.into();
    keyframe
}

/// Keyframe `id` of a robot's session in map `map`; its descriptor is
/// `[id, 1]`.
pub(super) fn kf_of(robot: &str, session: &str, id: u64, map: u64) -> SemanticKeyframe {
    SemanticKeyframe {
        key: KeyframeKey {
            robot_id: robot.into(),
            session_id: session.into(),
            keyframe_id: id,
        },
        frame_id: id * 10,
        timestamp: id as f64,
        map_id: map,
        pose: Pose::default(),
        features: Features {
            descriptor: vec![id as f32, 1.0],
            appearance: vec![],
            scene: vec![],
            objects: vec![ObjectObservation {
                class_name: "sign".into(),
                confidence: 1.0,
                centroid: [0.5, 0.5],
                area: 0.1,
                texts: vec![TextObservation {
                    text: format!("t{id}"),
                    confidence: 1.0,
                }],
            }],
        },
    }
}

fn prev_id(index: &Index, session: &str, id: u64) -> Option<u64> {
    let key = KeyframeKey {
        robot_id: "r".into(),
        session_id: session.into(),
        keyframe_id: id,
    };
    let row = index.row_of(&key)?;
    index
        .predecessor(row)
        .map(|r| index.meta(r).key.keyframe_id)
}

/// Checks every invariant against a from-scratch recomputation.
pub(super) fn check(index: &Index) {
    assert_eq!(index.matrix.len(), index.rows.len());
    assert_eq!(index.by_key.len(), index.rows.len());
    assert_eq!(index.ids.len(), index.rows.len());
    assert_eq!(index.tags.len(), index.rows.len());
    assert_eq!(index.appearance.len(), index.rows.len());
    for (row, meta) in index.rows.iter().enumerate() {
        assert_eq!(index.by_key[&meta.key], row);
        assert_eq!(index.tracks[&meta.map_key()][&meta.key.keyframe_id], row);
        assert_eq!(
            index.tags[row],
            crate::vpr::calibration::sample_tag(&meta.key)
        );
        assert_eq!(index.matrix.row(row)[0], meta.key.keyframe_id as f32);
        let ids = index.ids[row];
        assert_eq!(
            (ids.keyframe_id, ids.frame_id, ids.map_id),
            (meta.key.keyframe_id, meta.frame_id, meta.map_id)
        );
        let expected_prev = index
            .rows
            .iter()
            .enumerate()
            .filter(|(_, m)| {
                m.map_key() == meta.map_key() && m.key.keyframe_id < meta.key.keyframe_id
            })
            .max_by_key(|(_, m)| m.key.keyframe_id)
            .map(|(r, _)| r);
        assert_eq!(index.prev(row), expected_prev, "prev of {:?}", meta.key);
    }
    let tracked: usize = index.tracks.values().map(|t| t.len()).sum();
    assert_eq!(tracked, index.rows.len());
    // Each map's sampled subset: exactly its keyframes whose tag the
    // subset's mask keeps, with their tags.
    let mut sampled: HashMap<MapKey, BTreeMap<u64, u32>> = HashMap::new();
    for (row, meta) in index.rows.iter().enumerate() {
        if index.tags[row] & super::eligible::SAMPLED_MASK == 0 {
            sampled
                .entry(meta.map_key())
                .or_default()
                .insert(meta.key.keyframe_id, index.tags[row]);
        }
    }
    assert_eq!(index.sampled, sampled);
}

#[test]
fn erasures_are_counted_per_session_and_replacements_are_not() {
    let mut index = Index::new(0);
    let session = |name: &str| kf_of("r", name, 0, 0).key.session();
    index.upsert(kf("s", 1, 0, "a"));
    index.upsert(kf("s", 2, 0, "b"));
    index.upsert(kf("t", 1, 0, "c"));
    // A replaced keyframe is the same keyframe: no erasure.
    index.upsert(kf("s", 1, 0, "a2"));
    assert_eq!(index.session_erasures(&session("s")), 0);
    assert!(index.remove(&kf("s", 1, 0, "").key));
    assert!(!index.remove(&kf("s", 1, 0, "").key), "already gone");
    assert!(index.remove(&kf("s", 2, 0, "").key));
    assert_eq!(index.session_erasures(&session("s")), 2);
    assert_eq!(index.session_erasures(&session("t")), 0);
    // The count outlives the session's keyframes, so it never repeats.
    index.upsert(kf("s", 3, 0, "d"));
    assert_eq!(index.session_erasures(&session("s")), 2);
}

#[test]
fn predecessors_follow_keyframe_order_within_a_map() {
    let mut index = Index::new(0);
    for id in [3, 1, 2, 5] {
        index.upsert(kf("s", id, 0, "x"));
    }
    index.upsert(kf("s", 4, 1, "x"));
    check(&index);
    assert_eq!(prev_id(&index, "s", 1), None);
    assert_eq!(prev_id(&index, "s", 2), Some(1));
    assert_eq!(prev_id(&index, "s", 3), Some(2));
    assert_eq!(prev_id(&index, "s", 5), Some(3));
    assert_eq!(prev_id(&index, "s", 4), None, "other map");
}

#[test]
fn removal_and_swaps_keep_links_right() {
    let mut index = Index::new(0);
    for id in 0..20 {
        index.upsert(kf(if id % 2 == 0 { "a" } else { "b" }, id, id % 3, "x"));
    }
    for id in [0, 7, 19, 10, 4] {
        let key = index
            .rows
            .iter()
            .find(|m| m.key.keyframe_id == id)
            .unwrap()
            .key
            .clone();
        assert!(index.remove(&key));
        assert!(!index.remove(&key));
        check(&index);
    }
    let key = index.rows[3].key.clone();
    assert!(index.update_pose(&key, Pose::default(), Some(9)));
    check(&index);
    assert_eq!(index.len(), 15);
}

/// The spacing is the median step between consecutive keyframes (by
/// id, not insertion order) and follows inserts, pose updates, moves
/// to another map and removals.
#[test]
fn map_spacing_is_the_median_step_and_follows_changes() {
    let at = |id: u64, x: f64| {
        let mut k = kf("s", id, 0, "x");
        k.pose.translation = [x, 0.0, 0.0];
        k
    };
    let map = MapKey {
        session: SessionKey {
            robot_id: "r".into(),
            session_id: "s".into(),
        },
        map_id: 0,
    };
    let key = |id: u64| KeyframeKey {
        robot_id: "r".into(),
        session_id: "s".into(),
        keyframe_id: id,
    };
    let mut index = Index::new(0);
    assert_eq!(index.map_spacing(&map), 0.0, "unknown map");
    index.upsert(at(1, 0.0));
    assert_eq!(index.map_spacing(&map), 0.0, "one keyframe");
    // Ids 1..4 at x = 0, 1, 3, 10 (inserted out of order): steps 1, 2, 7.
    for (id, x) in [(4, 10.0), (2, 1.0), (3, 3.0)] {
        index.upsert(at(id, x));
    }
    assert_eq!(index.map_spacing(&map), 2.0);
    assert_eq!(index.place(&key(2)).unwrap().spacing, 2.0);
    // A corrected pose: id 4 at x = 3.5 (steps 1, 2, 0.5).
    let pose = Pose {
        translation: [3.5, 0.0, 0.0],
        ..Pose::default()
    };
    index.update_pose(&key(4), pose, None);
    assert_eq!(index.map_spacing(&map), 1.0);
    // Id 3 moves to map 1: steps 1, 2.5; the median is the upper one.
    index.update_pose(
        &key(3),
        index.meta(index.row_of(&key(3)).unwrap()).pose,
        Some(1),
    );
    assert_eq!(index.map_spacing(&map), 2.5);
    index.remove(&key(4));
    assert_eq!(index.map_spacing(&map), 1.0);
}

#[test]
fn replacing_a_keyframe_keeps_one_row() {
    let mut index = Index::new(0);
    assert!(!index.upsert(kf("s", 1, 0, "x")));
    assert!(index.upsert(kf("s", 1, 0, "y")));
    assert_eq!(index.len(), 1);
    check(&index);
}

#[test]
fn document_frequency_counts_keyframes() {
    let mut index = Index::new(0);
    index.upsert(kf("s", 1, 0, "Exit 12"));
    index.upsert(kf("s", 2, 0, "EXIT-12"));
    index.upsert(kf("s", 3, 0, "Room 5"));
    let exit = vpr::text::normalize("exit 12");
    assert_eq!(index.text_document_frequency(&exit), 2);
    let key = index.rows[0].key.clone();
    index.remove(&key);
    assert_eq!(index.text_document_frequency(&exit), 1);
    assert_eq!(index.keyframe_count(), 2);
}

#[test]
fn the_rows_a_tag_mask_keeps_are_those_a_row_by_row_walk_keeps() {
    let mut index = Index::new(0);
    // Enough rows for whole chunks and a ragged end, some erased.
    for id in 0..1000 {
        index.upsert(kf("s", id, id % 3, "x"));
    }
    for id in (0..1000).step_by(7) {
        let key = kf("s", id, 0, "x").key;
        index.remove(&key);
    }
    for mask in [0, 1, 3, 7, 31, 255, u32::MAX] {
        let walked: Vec<usize> = (0..index.len())
            .filter(|&row| index.sample_tag(row) & mask == 0)
            .collect();
        assert_eq!(index.rows_tagged(mask), walked, "mask {mask:#x}");
    }
    assert_eq!(index.rows_tagged(0).len(), index.len());
}

mod kept_paths {
    use super::*;
    use proptest::prelude::*;

    /// What a change does to the store: a keyframe of one session stored
    /// (or replaced) at `x`, erased, its pose updated to `x`, or moved to
    /// another map; or a query, which extends the kept paths.
    #[derive(Debug, Clone)]
    enum Change {
        Store { id: u8, map: u8, x: i16 },
        Erase { id: u8 },
        Correct { id: u8, x: i16 },
        Move { id: u8, map: u8 },
        Ask { id: u8 },
    }

    fn change() -> impl Strategy<Value = Change> {
        prop_oneof![
            4 => (0..40u8, 0..2u8, -500..500i16).prop_map(|(id, map, x)| Change::Store { id, map, x }),
            1 => (0..40u8).prop_map(|id| Change::Erase { id }),
            2 => (0..40u8, -500..500i16).prop_map(|(id, x)| Change::Correct { id, x }),
            1 => (0..40u8, 0..2u8).prop_map(|(id, map)| Change::Move { id, map }),
            3 => (0..40u8).prop_map(|id| Change::Ask { id }),
        ]
    }

    fn key(id: u8) -> KeyframeKey {
        kf_of("r", "s", u64::from(id), 0).key
    }

    fn at(x: i16) -> Pose {
        Pose {
            translation: [f64::from(x), f64::from(x % 7), 0.0],
            ..Pose::default()
        }
    }

    /// The path between `row` and every row of its map, walked from
    /// scratch over its track.
    fn walked(index: &Index, row: usize) -> Vec<Option<f64>> {
        let mut along = std::collections::HashMap::new();
        let (mut walked, mut previous) = (0.0, None);
        for (&id, &r) in &index.tracks[&index.meta(row).map_key()] {
            let here = index.meta(r).pose.translation;
            if let Some(p) = previous {
                walked += crate::vpr::feedback::squared_distance(p, here).sqrt();
            }
            previous = Some(here);
            along.insert(id, walked);
        }
        let query = along[&index.meta(row).key.keyframe_id];
        (0..index.len())
            .map(|r| {
                let same = index.meta(r).same_map(index.meta(row));
                same.then(|| (along[&index.meta(r).key.keyframe_id] - query).abs())
            })
            .collect()
    }

    proptest! {
        /// Whatever changes come between the queries, the kept paths give
        /// exactly the paths of a walk from scratch, and the spacing its
        /// median step.
        #[test]
        fn kept_paths_equal_a_walk_from_scratch(changes in proptest::collection::vec(change(), 1..150)) {
            let mut index = Index::new(0);
            for change in changes {
                match change {
                    Change::Store { id, map, x } => {
                        let mut kf = kf_of("r", "s", u64::from(id), u64::from(map));
                        kf.pose = at(x);
                        index.upsert(kf);
                    }
                    Change::Erase { id } => {
                        index.remove(&key(id));
                    }
                    Change::Correct { id, x } => {
                        index.update_pose(&key(id), at(x), None);
                    }
                    Change::Move { id, map } => {
                        if let Some(row) = index.row_of(&key(id)) {
                            let pose = index.meta(row).pose;
                            index.update_pose(&key(id), pose, Some(u64::from(map)));
                        }
                    }
                    Change::Ask { id } => {
                        if let Some(row) = index.row_of(&key(id)) {
                            let rows: Vec<usize> = (0..index.len()).collect();
                            prop_assert_eq!(index.track_paths(row, &rows), walked(&index, row));
                        }
                    }
                }
            }
            for row in 0..index.len() {
                let rows: Vec<usize> = (0..index.len()).collect();
                prop_assert_eq!(index.track_paths(row, &rows), walked(&index, row));
            }
        }
    }
}
