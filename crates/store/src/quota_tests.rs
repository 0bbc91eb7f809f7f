//! The keyframe quota as the writer checks it: exact under concurrent
//! inserts, replacements add nothing, removals make room, refusals store
//! nothing, and a failed flush gives back the count it took.

use super::tests::{kf, open_when_free, session};
use super::*;

fn within(keyframes: Vec<SemanticKeyframe>, max: u64) -> Mutation {
    Mutation::InsertWithin {
        keyframes,
        max_per_robot: max,
    }
}

#[tokio::test]
async fn concurrent_inserts_never_pass_the_quota_together() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), 0, 256).unwrap();
    // 60 inserts of one new keyframe each, all queued before any is
    // applied; another robot is counted apart.
    let writes: Vec<_> = (0..60)
        .map(|i| {
            let store = store.clone();
            tokio::spawn(async move { store.apply(within(vec![kf("a", "s", i, 0)], 25)).await })
        })
        .collect();
    let mut stored = 0;
    for write in writes {
        match write.await.unwrap() {
            Ok(_) => stored += 1,
            Err(StoreError::QuotaExceeded {
                robot, held, max, ..
            }) => assert_eq!((robot.as_str(), held, max), ("a", 25, 25)),
            Err(e) => panic!("{e}"),
        }
    }
    assert_eq!(stored, 25);
    assert_eq!(store.index().robot_keyframes("a"), 25);
    store
        .apply(within(vec![kf("b", "s", 0, 0)], 25))
        .await
        .unwrap();

    // A batch that would pass it is refused whole and stores nothing.
    let held: Vec<u64> = (0..60)
        .filter(|i| store.get(&session("a", "s").keyframe(*i)).is_some())
        .collect();
    let free: Vec<u64> = (0..60).filter(|i| !held.contains(i)).collect();
    let refused = store
        .apply(within(
            vec![kf("a", "s", held[0], 0), kf("a", "s", free[0], 0)],
            25,
        ))
        .await
        .unwrap_err();
    assert!(refused.is_refusal(), "{refused}");
    assert!(refused.to_string().contains("storing 1 more"), "{refused}");
    assert!(store.get(&session("a", "s").keyframe(free[0])).is_none());
    // Replacing stored keyframes adds nothing.
    store
        .apply(within(
            vec![kf("a", "s", held[0], 0), kf("a", "s", held[1], 0)],
            25,
        ))
        .await
        .unwrap();
    // An erasure makes room for one.
    store
        .apply(Mutation::Erase {
            session: session("a", "s"),
            keyframe_ids: vec![held[0]],
        })
        .await
        .unwrap();
    store
        .apply(within(vec![kf("a", "s", free[0], 0)], 25))
        .await
        .unwrap();
    // A failed flush takes back what its group counted.
    store.fail_next_flushes(1);
    store
        .apply(Mutation::Erase {
            session: session("a", "s"),
            keyframe_ids: vec![free[0]],
        })
        .await
        .unwrap_err();
    store
        .apply(within(vec![kf("a", "s", free[1], 0)], 25))
        .await
        .unwrap_err();
    // And the counts are rebuilt at open.
    drop(store);
    let store = open_when_free(dir.path(), 0).unwrap();
    assert_eq!(store.index().robot_keyframes("a"), 25);
    store
        .apply(within(vec![kf("a", "s", free[1], 0)], 25))
        .await
        .unwrap_err();
    store
        .apply(within(vec![kf("a", "s", free[1], 0)], 26))
        .await
        .unwrap();
}
