//! Replicated-log application: positions are recorded with their changes,
//! survive a reopen, advance past refusals, and never pass a change that
//! could not be applied.

use super::tests::{kf, open_when_free, session};
use super::*;

fn entry(position: u64, mutation: Mutation) -> LogEntry {
    LogEntry { position, mutation }
}

#[tokio::test]
async fn positions_are_recorded_and_survive_a_reopen() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = Store::open(dir.path(), 0, 16).unwrap();
        assert_eq!(store.log_position().unwrap(), 0);
        let applied = store
            .apply_log(vec![
                entry(
                    1,
                    Mutation::Insert(vec![kf("a", "s", 1, 0), kf("a", "s", 2, 0)]),
                ),
                entry(2, Mutation::Insert(vec![kf("a", "s", 3, 0)])),
                // Wrong length: refused on every replica, position still
                // recorded, the next entry goes on.
                entry(
                    3,
                    Mutation::Insert(vec![SemanticKeyframe {
                        features: humem_core::keyframe::Features {
                            descriptor: vec![1.0; 5],
                            ..Default::default()
                        },
                        ..kf("a", "s", 4, 0)
                    }]),
                ),
                // Erasing what is absent writes no keyframe, but is recorded.
                entry(
                    4,
                    Mutation::Erase {
                        session: session("a", "s"),
                        keyframe_ids: vec![99],
                    },
                ),
            ])
            .await
            .unwrap();
        assert!(applied.stopped.is_none());
        assert_eq!(applied.results.len(), 4);
        assert_eq!(applied.results[1].as_ref().unwrap().store_keyframes, 3);
        assert!(matches!(
            applied.results[2],
            Err(StoreError::DimensionMismatch {
                expected: 3,
                found: 5
            })
        ));
        assert_eq!(applied.results[3].as_ref().unwrap().affected, 0);
        assert_eq!(store.log_position().unwrap(), 4);
        let applied = store
            .apply_log(vec![entry(
                5,
                Mutation::Erase {
                    session: session("a", "s"),
                    keyframe_ids: vec![1],
                },
            )])
            .await
            .unwrap();
        assert_eq!(applied.results[0].as_ref().unwrap().affected, 1);
    }
    let store = open_when_free(dir.path(), 0).unwrap();
    assert_eq!(store.log_position().unwrap(), 5);
    assert_eq!(store.index().len(), 2);
}

#[tokio::test]
async fn applying_the_same_entries_again_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), 0, 16).unwrap();
    let entries = || {
        vec![
            entry(
                1,
                Mutation::Insert((0..4).map(|i| kf("a", "s", i, 0)).collect()),
            ),
            entry(
                2,
                Mutation::UpdatePoses {
                    session: session("a", "s"),
                    updates: vec![PoseUpdate {
                        keyframe_id: 2,
                        pose: kf("a", "s", 7, 0).pose,
                        map_id: Some(3),
                    }],
                },
            ),
            entry(
                3,
                Mutation::ResetMap(MapKey {
                    session: session("a", "s"),
                    map_id: 0,
                }),
            ),
        ]
    };
    store.apply_log(entries()).await.unwrap();
    let once: Vec<_> = store.index().map_counts().into_iter().collect();
    let again = store.apply_log(entries()).await.unwrap();
    assert!(again.stopped.is_none());
    let twice: Vec<_> = store.index().map_counts().into_iter().collect();
    assert_eq!(once, twice);
    assert_eq!(once.len(), 1, "only keyframe 2, moved to map 3, is left");
    assert_eq!(once[0].0.map_id, 3);
}

#[tokio::test]
async fn a_full_disk_stops_the_batch_at_the_first_insert() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open_with(
        dir.path(),
        StoreOptions {
            // More than any disk has free: every insert is refused.
            min_free_bytes: u64::MAX / 2,
            ..StoreOptions::default()
        },
        humem_core::observe::unobserved(),
    )
    .unwrap();
    let applied = store
        .apply_log(vec![
            entry(
                1,
                Mutation::Erase {
                    session: session("a", "s"),
                    keyframe_ids: vec![1],
                },
            ),
            entry(2, Mutation::Insert(vec![kf("a", "s", 1, 0)])),
            entry(3, Mutation::ResetSession(session("a", "s"))),
        ])
        .await
        .unwrap();
    assert_eq!(applied.results.len(), 1, "the removal before it is applied");
    assert!(matches!(applied.stopped, Some(StoreError::DiskFull { .. })));
    assert_eq!(
        store.log_position().unwrap(),
        1,
        "nothing after the refused insert is recorded"
    );
}
