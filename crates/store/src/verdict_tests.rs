//! Verdicts in the store: durable, replaced per pair and kind, refused for
//! keyframes that are not stored, and carried away with either keyframe by
//! every kind of removal, on disk as in memory.

use super::tests::{kf, open_when_free, session};
use super::*;
use crate::layout::{VERDICTS_BY_CANDIDATE_TREE, VERDICTS_TREE};

/// A loop verdict on keyframes `query` and `candidate` of robot r, session s.
pub(crate) fn verdict(query: u64, candidate: u64, accepted: bool) -> Verdict {
    Verdict {
        query: session("r", "s").keyframe(query),
        candidate: session("r", "s").keyframe(candidate),
        kind: VerificationKind::Loop,
        accepted,
        relative: None,
        score: Some(0.5),
        inliers: 40,
        reported_at: 1.0e9,
    }
}

/// The verdicts of the index and of a store reopened from disk, sorted.
fn verdicts(store: &Store) -> Vec<(u64, u64, bool)> {
    let mut v: Vec<_> = store
        .index()
        .verdicts()
        .iter()
        .map(|v| (v.query.keyframe_id, v.candidate.keyframe_id, v.accepted))
        .collect();
    v.sort();
    v
}

#[tokio::test]
async fn verdicts_persist_replace_and_follow_every_removal() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), 0, 16).unwrap();
    store
        .apply(Mutation::Insert(
            (0..6).map(|i| kf("r", "s", i, 0)).collect(),
        ))
        .await
        .unwrap();
    let out = store
        .apply(Mutation::ReportVerdict(verdict(5, 1, false)))
        .await
        .unwrap();
    assert_eq!((out.replaced, out.store_verdicts), (0, 1));
    // The newest verdict on the same pair and kind replaces the older.
    let out = store
        .apply(Mutation::ReportVerdict(verdict(5, 1, true)))
        .await
        .unwrap();
    assert_eq!((out.replaced, out.store_verdicts), (1, 1));
    for (q, c) in [(5, 2), (4, 1), (3, 0)] {
        store
            .apply(Mutation::ReportVerdict(verdict(q, c, false)))
            .await
            .unwrap();
    }
    // Unknown keyframes are refused, naming the end, and change nothing.
    let refused = store
        .apply(Mutation::ReportVerdict(verdict(5, 99, false)))
        .await
        .unwrap_err();
    assert!(
        matches!(
            refused,
            StoreError::UnknownKeyframe {
                role: "candidate",
                ..
            }
        ),
        "{refused}"
    );
    assert!(refused.is_refusal());
    let all = vec![(3, 0, false), (4, 1, false), (5, 1, true), (5, 2, false)];
    assert_eq!(verdicts(&store), all);
    // A replaced keyframe keeps its verdicts.
    store
        .apply(Mutation::Insert(vec![kf("r", "s", 1, 0)]))
        .await
        .unwrap();
    assert_eq!(verdicts(&store), all);

    // Across a restart (the snapshot written at open holds no verdicts:
    // they come from their own tree).
    drop(store);
    let store = open_when_free(dir.path(), 0).unwrap();
    assert_eq!(verdicts(&store), all);

    // Erasing a candidate takes its verdicts (as candidate), on disk too.
    store
        .apply(Mutation::Erase {
            session: session("r", "s"),
            keyframe_ids: vec![1],
        })
        .await
        .unwrap();
    assert_eq!(verdicts(&store), vec![(3, 0, false), (5, 2, false)]);
    // Erasing a query takes its verdicts (as query).
    store
        .apply(Mutation::Erase {
            session: session("r", "s"),
            keyframe_ids: vec![5],
        })
        .await
        .unwrap();
    assert_eq!(verdicts(&store), vec![(3, 0, false)]);
    drop(store);
    let store = open_when_free(dir.path(), 0).unwrap();
    assert_eq!(verdicts(&store), vec![(3, 0, false)]);
    // A map reset takes the rest.
    store
        .apply(Mutation::ResetMap(MapKey {
            session: session("r", "s"),
            map_id: 0,
        }))
        .await
        .unwrap();
    assert!(verdicts(&store).is_empty());
    drop(store);
    let store = open_when_free(dir.path(), 0).unwrap();
    assert!(verdicts(&store).is_empty());
    let tree = store.db.open_tree(VERDICTS_TREE).unwrap();
    let by_candidate = store.db.open_tree(VERDICTS_BY_CANDIDATE_TREE).unwrap();
    assert!(tree.is_empty() && by_candidate.is_empty());
}

#[tokio::test]
async fn a_session_reset_takes_verdicts_naming_it_from_other_sessions() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), 0, 16).unwrap();
    store
        .apply(Mutation::Insert(vec![
            kf("r", "s", 1, 0),
            kf("r", "t", 2, 0),
            kf("r", "t", 3, 0),
        ]))
        .await
        .unwrap();
    let mut across = verdict(2, 1, false);
    across.query = session("r", "t").keyframe(2);
    let mut within = verdict(3, 2, true);
    within.query = session("r", "t").keyframe(3);
    within.candidate = session("r", "t").keyframe(2);
    for v in [across, within] {
        store.apply(Mutation::ReportVerdict(v)).await.unwrap();
    }
    assert_eq!(store.index().verdicts().len(), 2);
    store
        .apply(Mutation::ResetSession(session("r", "s")))
        .await
        .unwrap();
    assert_eq!(verdicts(&store), vec![(3, 2, true)]);
    drop(store);
    let store = open_when_free(dir.path(), 0).unwrap();
    assert_eq!(verdicts(&store), vec![(3, 2, true)]);
}
