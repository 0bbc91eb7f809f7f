//! An exact pass in pieces against the pass in one hold: the same answer
//! bit for bit on a store that does not change, rows appended between
//! pieces included, and a start over when rows are renumbered.

use std::cell::Cell;
use std::sync::RwLock;

use proptest::prelude::*;

use super::answer_in_pieces_of;
use crate::engine::filter::RowFilter;
use crate::index::Index;
use crate::index_scan_tests::{context_of, index_of, keyframe, store_strategy, ROBOTS, SESSIONS};
use crate::keyframe::{Features, SceneClass, SessionKey};
use crate::query::{answer, Answer, IndexQuery};
use crate::vpr::eligibility::{QueryContext, Scope};
use crate::vpr::params::{Layers, ScanMode, VprParams};
use crate::vpr::rank::QueryObservation;
use crate::vpr::testing::{features_of, scene_strategy, scope_strategy, unit_vector};

/// Every ranked candidate's row, scores, null model and `S_s`, as bits.
fn bits(answer: &Answer) -> Vec<(usize, u32, u32, u32, usize, u32)> {
    answer
        .candidates
        .iter()
        .map(|c| {
            (
                c.row,
                c.score.to_bits(),
                c.raw_score.to_bits(),
                c.null.location.to_bits(),
                c.null.samples,
                c.scene.score.to_bits(),
            )
        })
        .collect()
}

/// Codes first at any size, so that every store is scanned in pieces.
fn compressed(top_k: usize) -> VprParams {
    VprParams {
        scan: ScanMode::Compressed,
        top_k,
        ..VprParams::default()
    }
}

/// An exact query of `context` for `history`, every ranked candidate kept.
fn exact_query<'a>(context: QueryContext, history: &'a [Features]) -> IndexQuery<'a> {
    IndexQuery {
        observation: QueryObservation {
            history: history.iter().collect(),
        },
        context,
        layers: Layers::default(),
        stored_row: None,
        threshold: Some(0.0),
        top_n: usize::MAX,
        partitioned: true,
        exact: true,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    #[test]
    fn an_exact_pass_in_pieces_answers_as_the_pass_in_one_hold(
        rows in store_strategy(),
        query in (0usize..6, 0usize..2, 0u64..120, 0u64..3, 0u64..40),
        scope in scope_strategy(ROBOTS, SESSIONS),
        readable in prop::option::of(prop::collection::vec(
            prop::sample::select(ROBOTS).prop_map(str::to_string), 0..4)),
        history in prop::collection::vec((unit_vector(6), scene_strategy()), 1..4),
        k in 1usize..12,
        piece_rows in 1usize..40,
        partitioned: bool,
    ) {
        let index = index_of(rows, None);
        let (robot, session, frame_id, map_id, min_frame_gap) = query;
        let context = context_of(
            (robot, session, None, frame_id, map_id, min_frame_gap),
            scope,
            readable,
        );
        let history = features_of(history);
        let params = compressed(k);
        let query = IndexQuery { partitioned, ..exact_query(context, &history) };
        let whole = answer(&index, &params, &query);
        let holds = Cell::new(1);
        let (_, pieces) = answer_in_pieces_of(piece_rows, &index, || {
            holds.set(holds.get() + 1);
            &index
        }, &params, &query);
        prop_assert_eq!(bits(&whole), bits(&pieces));
        prop_assert_eq!(whole.eligible, pieces.eligible);
        // The pass let the index go between its pieces.
        let visited = if partitioned {
            index.eligibility(&query.context).partition().map_or(index.len(), <[usize]>::len)
        } else {
            index.len()
        };
        if visited > piece_rows {
            prop_assert_eq!(holds.get(), visited.div_ceil(piece_rows));
        } else {
            prop_assert_eq!(holds.get(), 1);
        }
    }
}

/// Four robots, one map each, 50 keyframes each, with distinct
/// descriptors.
fn fleet() -> Index {
    let rows = (0..4)
        .flat_map(|robot| {
            (0..50u64).map(move |id| {
                let mut descriptor = vec![0.2f32; 6];
                descriptor[robot] = 1.0;
                descriptor[4] = (id % 7) as f32 / 7.0;
                descriptor[5] = (id % 11) as f32 / 11.0;
                (robot, 0, 0, id, unit(descriptor), Vec::new())
            })
        })
        .collect();
    index_of(rows, None)
}

fn unit(v: Vec<f32>) -> Vec<f32> {
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.into_iter().map(|x| x / norm).collect()
}

/// Robot 4's merge query (every other map) for a descriptor.
fn merge_query_history() -> (QueryContext, Vec<Features>) {
    let context = QueryContext {
        session: SessionKey {
            robot_id: ROBOTS[4].into(),
            session_id: SESSIONS[0].into(),
        },
        keyframe_id: None,
        frame_id: 0,
        map_id: 0,
        min_frame_gap: 0,
        scope: Scope::OtherMaps,
        readable_robots: None,
    };
    let history = vec![Features {
        descriptor: unit(vec![0.3, 0.9, 0.1, 0.4, 0.5, 0.2]),
        ..Features::default()
    }];
    (context, history)
}

#[test]
fn a_keyframe_stored_between_pieces_is_scanned_last() {
    let lock = RwLock::new(fleet());
    let (context, history) = merge_query_history();
    let params = compressed(8);
    let query = exact_query(context, &history);
    // Its descriptor is the query's own: the best match once stored.
    let look_alike = keyframe(
        2,
        1,
        0,
        7,
        Features {
            descriptor: history[0].descriptor.clone(),
            ..Features::default()
        },
    );
    let holds = Cell::new(1);
    let read = || {
        holds.set(holds.get() + 1);
        if holds.get() == 3 {
            let mut index = lock.write().unwrap();
            // The writer is asked to leave the rows' order alone.
            assert!(index.row_order_held());
            index.upsert(look_alike.clone());
        }
        lock.read().unwrap()
    };
    let (index, pieces) = answer_in_pieces_of(16, lock.read().unwrap(), read, &params, &query);
    assert!(!index.row_order_held(), "for as long as the pass lasts");
    let stored = index.row_of(&look_alike.key).expect("stored");
    assert_eq!(stored, 200, "appended after the first pass's rows");
    assert_eq!(pieces.candidates[0].row, stored);
    let whole = answer(&index, &params, &query);
    assert_eq!(bits(&whole), bits(&pieces));
    assert_eq!(holds.get(), 200 / 16 + 1, "one hold a piece");
}

#[test]
fn a_pass_whose_rows_were_renumbered_starts_over() {
    let lock = RwLock::new(fleet());
    let (mut context, history) = merge_query_history();
    // The query is robot 3's last keyframe, which the removal moves.
    context.session.robot_id = ROBOTS[3].into();
    context.keyframe_id = Some(49);
    let query_key = context.session.keyframe(49);
    let params = compressed(8);
    let first = lock.read().unwrap();
    let query = IndexQuery {
        stored_row: first.row_of(&query_key),
        ..exact_query(context, &history)
    };
    assert_eq!(query.stored_row, Some(199));
    let removed = keyframe(0, 0, 0, 3, Features::default()).key;
    let holds = Cell::new(1);
    let read = || {
        holds.set(holds.get() + 1);
        if holds.get() == 3 {
            assert!(lock.write().unwrap().remove(&removed));
        }
        lock.read().unwrap()
    };
    let (index, pieces) = answer_in_pieces_of(16, first, read, &params, &query);
    let moved = index.row_of(&query_key);
    assert_eq!(moved, Some(3), "the last row filled the hole");
    let whole = answer(
        &index,
        &params,
        &IndexQuery {
            stored_row: moved,
            ..query.clone()
        },
    );
    assert_eq!(bits(&whole), bits(&pieces));
    // Two pieces, then a whole pass in pieces again.
    assert_eq!(holds.get(), 2 + 199usize.div_ceil(16));
}

#[test]
fn a_pass_renumbered_at_every_piece_holds_the_index_at_last() {
    let lock = RwLock::new(fleet());
    let (context, history) = merge_query_history();
    let params = compressed(8);
    let query = exact_query(context, &history);
    let next_removal = Cell::new(0u64);
    let read = || {
        let id = next_removal.get();
        next_removal.set(id + 1);
        assert!(lock
            .write()
            .unwrap()
            .remove(&keyframe(1, 0, 0, id, Features::default()).key));
        lock.read().unwrap()
    };
    let (index, pieces) = answer_in_pieces_of(16, lock.read().unwrap(), read, &params, &query);
    // Each of the three starts saw a removal at its second piece.
    assert_eq!(next_removal.get(), 3);
    assert_eq!(index.len(), 197);
    assert_eq!(bits(&answer(&index, &params, &query)), bits(&pieces));
}

/// One of three scene classes, certain, or none.
fn scene(draw: u64) -> Vec<SceneClass> {
    match draw % 4 {
        3 => Vec::new(),
        class => vec![SceneClass {
            class_id: class as u32,
            probability: 1.0,
        }],
    }
}

#[test]
fn a_large_pass_in_pieces_ranks_and_samples_as_the_pass_in_one_hold() {
    use crate::synthetic::{place_descriptor, place_of, Rng};
    // Six drives through 300 places, 1 000 keyframes each, five of them
    // other maps than the query's: the null sample's stride is 3, and many
    // keyframes of a place come close to the query; scenes that lower
    // their scores by up to half and three steps of temporal context
    // order the bounds otherwise than the exact scores, so rows beyond
    // the seeds are open in every piece.
    let mut noise = Rng::new(7);
    let rows = (0..6usize)
        .flat_map(|robot| (0..1000u64).map(move |id| (robot, id)))
        .map(|(robot, id)| {
            let place = place_of(300, robot as u64, id);
            let descriptor = place_descriptor(6, place, &mut noise);
            (robot % 5, robot / 5, 0, id, descriptor, scene(noise.next()))
        })
        .collect();
    let index = index_of(rows, None);
    let (context, _) = merge_query_history();
    for place in [3, 150, 299] {
        let history: Vec<Features> = (0..3)
            .map(|_| Features {
                descriptor: place_descriptor(6, place, &mut noise),
                scene: scene(noise.next()),
                ..Features::default()
            })
            .collect();
        for (k, piece_rows) in [(24, 700), (4, 1500), (2, 2500)] {
            let params = compressed(k);
            let query = exact_query(context.clone(), &history);
            let whole = answer(&index, &params, &query);
            assert_eq!(whole.candidates[0].null.samples, 5000);
            let (_, pieces) = answer_in_pieces_of(piece_rows, &index, || &index, &params, &query);
            assert_eq!(
                bits(&whole),
                bits(&pieces),
                "place {place}, {k} of {piece_rows}"
            );
        }
    }
}
