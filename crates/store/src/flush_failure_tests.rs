//! A failed flush leaves sled's trees and the in-memory index equal: every
//! kind of change whose flush fails is refused to its caller, is absent
//! from the index, and is absent from the tree, also after a later flush
//! succeeds and after a reopen (issue 32, item 1).

use super::tests::{kf, open_when_free, session};
use super::verdict_tests::verdict;
use super::*;
use crate::layout::{KEYFRAMES_TREE, VERDICTS_BY_CANDIDATE_TREE, VERDICTS_TREE};
use humem_core::keyframe::Pose;

/// One keyframe as the store holds it: key, map and x of the pose.
type Row = (String, u64, u64, i64);
/// A verdict as the store holds it: query, candidate, accepted.
type Judged = (u64, u64, bool);

/// What the index holds.
fn in_index(store: &Store) -> (Vec<Row>, Vec<Judged>) {
    let index = store.index();
    let mut rows: Vec<Row> = (0..index.len())
        .map(|row| {
            let kf = index.keyframe(row);
            (
                kf.key.session_id.clone(),
                kf.key.keyframe_id,
                kf.map_id,
                kf.pose.translation[0] as i64,
            )
        })
        .collect();
    rows.sort();
    let mut judged: Vec<Judged> = index
        .verdicts()
        .iter()
        .map(|v| (v.query.keyframe_id, v.candidate.keyframe_id, v.accepted))
        .collect();
    judged.sort();
    (rows, judged)
}

/// What sled's trees hold, read directly; the by-candidate tree must name
/// exactly the verdicts of the verdicts tree.
fn in_tree(store: &Store) -> (Vec<Row>, Vec<Judged>) {
    let keyframes = store.db.open_tree(KEYFRAMES_TREE).unwrap();
    let mut rows: Vec<Row> = keyframes
        .iter()
        .map(|item| {
            let (_, value) = item.unwrap();
            let kf = codec::decode_record(&value).unwrap();
            (
                kf.key.session_id,
                kf.key.keyframe_id,
                kf.map_id,
                kf.pose.translation[0] as i64,
            )
        })
        .collect();
    rows.sort();
    let tree = store.db.open_tree(VERDICTS_TREE).unwrap();
    let by_candidate = store.db.open_tree(VERDICTS_BY_CANDIDATE_TREE).unwrap();
    assert_eq!(
        tree.len(),
        by_candidate.len(),
        "the two verdict trees differ"
    );
    let mut judged: Vec<Judged> = tree
        .iter()
        .map(|item| {
            let (_, value) = item.unwrap();
            let v = codec::decode_verdict(&value).unwrap();
            (v.query.keyframe_id, v.candidate.keyframe_id, v.accepted)
        })
        .collect();
    judged.sort();
    (rows, judged)
}

fn assert_flush_failed(result: Result<MutationOutcome, StoreError>, what: &str) {
    match result {
        Err(StoreError::Flush(_)) => {}
        other => panic!("{what}: expected a flush failure, got {other:?}"),
    }
}

#[tokio::test]
async fn a_failed_flush_leaves_tree_and_index_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), 0, 16).unwrap();
    store
        .apply(Mutation::Insert(
            (0..5).map(|i| kf("r", "s", i, 0)).collect(),
        ))
        .await
        .unwrap();
    for (q, c, accepted) in [(3, 1, false), (4, 0, true)] {
        store
            .apply(Mutation::ReportVerdict(verdict(q, c, accepted)))
            .await
            .unwrap();
    }
    store
        .apply_log(vec![LogEntry {
            position: 7,
            mutation: Mutation::Insert(vec![kf("r", "log", 0, 0)]),
        }])
        .await
        .unwrap();
    let before = in_index(&store);
    assert_eq!(in_tree(&store), before);
    assert_eq!(before.0.len(), 6);
    assert_eq!(before.1.len(), 2);

    // Every kind of change, each in a group whose flush fails.
    let failing = vec![
        (
            "insert",
            Mutation::Insert(vec![kf("r", "s", 10, 0), kf("r", "s", 2, 9)]),
        ),
        (
            "erase (with its verdicts)",
            Mutation::Erase {
                session: session("r", "s"),
                keyframe_ids: vec![1, 4],
            },
        ),
        ("session reset", Mutation::ResetSession(session("r", "s"))),
        (
            "map reset",
            Mutation::ResetMap(MapKey {
                session: session("r", "s"),
                map_id: 0,
            }),
        ),
        (
            "pose update",
            Mutation::UpdatePoses {
                session: session("r", "s"),
                updates: vec![PoseUpdate {
                    keyframe_id: 2,
                    pose: Pose {
                        translation: [50.0, 0.0, 0.0],
                        rotation: [1.0, 0.0, 0.0, 0.0],
                    },
                    map_id: Some(3),
                }],
            },
        ),
        (
            "verdict replaced",
            Mutation::ReportVerdict(verdict(3, 1, true)),
        ),
        (
            "verdict added",
            Mutation::ReportVerdict(verdict(2, 0, false)),
        ),
    ];
    for (what, mutation) in failing {
        store.fail_next_flushes(1);
        assert_flush_failed(store.apply(mutation).await, what);
        assert_eq!(in_index(&store), before, "index after a failed {what}");
        assert_eq!(in_tree(&store), before, "tree after a failed {what}");
    }
    // A log entry whose flush fails leaves the position where it was, so
    // the replica applies it again.
    store.fail_next_flushes(1);
    let applied = store
        .apply_log(vec![LogEntry {
            position: 8,
            mutation: Mutation::Insert(vec![kf("r", "log", 1, 0)]),
        }])
        .await
        .unwrap();
    assert!(applied.results.is_empty());
    assert!(matches!(applied.stopped, Some(StoreError::Flush(_))));
    assert_eq!(store.log_position().unwrap(), 7);
    assert_eq!(in_tree(&store), before);

    // The next group flushes; only its own change becomes durable.
    let out = store
        .apply(Mutation::Insert(vec![kf("r", "s", 20, 0)]))
        .await
        .unwrap();
    assert_eq!(out.store_keyframes, 7);
    let mut after = before.clone();
    after.0.push(("s".into(), 20, 0, 20));
    after.0.sort();
    assert_eq!(in_index(&store), after);
    assert_eq!(in_tree(&store), after);

    // A reopen (index rebuilt from sled and its journal) agrees.
    drop(store);
    let store = open_when_free(dir.path(), 0).unwrap();
    assert_eq!(in_index(&store), after);
    assert_eq!(in_tree(&store), after);
    assert_eq!(store.log_position().unwrap(), 7);
    // And the write sequence goes on from where the durable journal ends.
    store
        .apply(Mutation::Erase {
            session: session("r", "s"),
            keyframe_ids: vec![20],
        })
        .await
        .unwrap();
    drop(store);
    let store = open_when_free(dir.path(), 0).unwrap();
    assert_eq!(in_index(&store), before);
}

#[tokio::test]
async fn a_failed_first_insert_does_not_fix_the_descriptor_length() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), 0, 16).unwrap();
    store.fail_next_flushes(1);
    assert_flush_failed(
        store
            .apply(Mutation::Insert(vec![kf("r", "s", 1, 0)]))
            .await,
        "first insert",
    );
    // The failed keyframe had 3 values; a 5-value one is now the first.
    let five = SemanticKeyframe {
        features: humem_core::keyframe::Features {
            descriptor: vec![0.5; 5],
            ..Default::default()
        },
        ..kf("r", "s", 2, 0)
    };
    store.apply(Mutation::Insert(vec![five])).await.unwrap();
    assert_eq!(store.index().dim(), 5);
    drop(store);
    assert_eq!(open_when_free(dir.path(), 0).unwrap().index().dim(), 5);
}
