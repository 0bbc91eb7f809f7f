//! Store tests: every change persists across a reopen, and the index agrees
//! with sled.

use super::*;
use crate::layout::{KEYFRAMES_TREE, META_FORMAT, META_TREE};
use humem_core::keyframe::{Features, ObjectObservation, Pose, SessionKey, TextObservation};

pub(crate) fn kf(robot: &str, session: &str, id: u64, map: u64) -> SemanticKeyframe {
    SemanticKeyframe {
        key: KeyframeKey {
            robot_id: robot.into(),
            session_id: session.into(),
            keyframe_id: id,
        },
        frame_id: id * 3,
        timestamp: id as f64 * 0.1,
        map_id: map,
        pose: Pose {
            translation: [id as f64, 0.0, 0.0],
            rotation: [1.0, 0.0, 0.0, 0.0],
        },
        features: Features {
            descriptor: vec![1.0, 0.0, id as f32],
            appearance: vec![],
            scene: vec![],
            objects: vec![ObjectObservation {
                class_name: "sign".into(),
                confidence: 0.8,
                centroid: [0.1, 0.2],
                area: 0.05,
                texts: vec![TextObservation {
                    text: format!("ROOM {id}"),
                    confidence: 0.9,
                }],
            }],
        },
    }
}

/// Opens a store again once the previous handle's writer thread has let go
/// of the directory (sled holds a lock on it until then).
pub(crate) fn open_when_free(dir: &std::path::Path, dim: usize) -> Result<Store, StoreError> {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        match Store::open(dir, dim, 16) {
            Err(StoreError::Open { .. }) if std::time::Instant::now() < deadline => {
                std::thread::sleep(std::time::Duration::from_millis(20))
            }
            result => return result,
        }
    }
}

/// Opens `dir` with `options`, waiting up to 5 s for the last handle of
/// it to let go.
pub(crate) fn open_retrying(dir: &std::path::Path, options: StoreOptions) -> Store {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        match Store::open_with(dir, options.clone(), humem_core::observe::unobserved()) {
            Err(StoreError::Open { .. }) if std::time::Instant::now() < deadline => {
                std::thread::sleep(std::time::Duration::from_millis(20))
            }
            result => return result.unwrap(),
        }
    }
}

fn reopen(dir: &std::path::Path, dim: usize) -> Store {
    open_when_free(dir, dim).unwrap()
}

pub(crate) fn session(robot: &str, session: &str) -> SessionKey {
    SessionKey {
        robot_id: robot.into(),
        session_id: session.into(),
    }
}

fn keys(store: &Store) -> Vec<(String, String, u64, u64)> {
    let index = store.index();
    let mut keys: Vec<_> = (0..index.len())
        .map(|row| {
            let m = index.meta(row);
            (
                m.key.robot_id.clone(),
                m.key.session_id.clone(),
                m.key.keyframe_id,
                m.map_id,
            )
        })
        .collect();
    keys.sort();
    keys
}

#[tokio::test]
async fn changes_survive_reopening() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = Store::open(dir.path(), 0, 16).unwrap();
        let batch: Vec<_> = (0..10).map(|i| kf("a", "s1", i, i / 5)).collect();
        let out = store.apply(Mutation::Insert(batch)).await.unwrap();
        assert_eq!(out.store_keyframes, 10);
        store
            .apply(Mutation::Insert(vec![
                kf("b", "s1", 0, 0),
                kf("a", "s2", 0, 0),
            ]))
            .await
            .unwrap();
        let out = store
            .apply(Mutation::Erase {
                session: session("a", "s1"),
                keyframe_ids: vec![1, 2, 99],
            })
            .await
            .unwrap();
        assert_eq!(out.affected, 2);
        let out = store
            .apply(Mutation::ResetMap(MapKey {
                session: session("a", "s1"),
                map_id: 1,
            }))
            .await
            .unwrap();
        assert_eq!(out.affected, 5);
        let out = store
            .apply(Mutation::ResetSession(session("a", "s2")))
            .await
            .unwrap();
        assert_eq!(out.affected, 1);
        let moved = Pose {
            translation: [9.0, 8.0, 7.0],
            rotation: [0.0, 1.0, 0.0, 0.0],
        };
        let out = store
            .apply(Mutation::UpdatePoses {
                session: session("a", "s1"),
                updates: vec![
                    PoseUpdate {
                        keyframe_id: 3,
                        pose: moved,
                        map_id: Some(7),
                    },
                    PoseUpdate {
                        keyframe_id: 42,
                        pose: moved,
                        map_id: None,
                    },
                ],
            })
            .await
            .unwrap();
        assert_eq!(out.affected, 1);
        assert_eq!(out.missing, vec![42]);
        assert_eq!(out.store_keyframes, 4);
    }
    let store = reopen(dir.path(), 0);
    assert_eq!(
        keys(&store),
        vec![
            ("a".into(), "s1".into(), 0, 0),
            ("a".into(), "s1".into(), 3, 7),
            ("a".into(), "s1".into(), 4, 0),
            ("b".into(), "s1".into(), 0, 0),
        ]
    );
    let got = store.get(&kf("a", "s1", 3, 0).key).unwrap();
    assert_eq!(got.pose.translation, [9.0, 8.0, 7.0]);
    assert_eq!(got.features, kf("a", "s1", 3, 0).features);
    assert_eq!(store.index().dim(), 3);
}

#[tokio::test]
async fn replacing_counts_and_keeps_one_copy() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), 0, 16).unwrap();
    let out = store
        .apply(Mutation::Insert(vec![kf("a", "s", 1, 0)]))
        .await
        .unwrap();
    assert_eq!(out.replaced, 0);
    let out = store
        .apply(Mutation::Insert(vec![kf("a", "s", 1, 2)]))
        .await
        .unwrap();
    assert_eq!((out.replaced, out.store_keyframes), (1, 1));
    assert_eq!(keys(&store), vec![("a".into(), "s".into(), 1, 2)]);
}

#[tokio::test]
async fn descriptor_length_is_fixed_by_the_first_keyframe_and_persisted() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = Store::open(dir.path(), 0, 16).unwrap();
        store
            .apply(Mutation::Insert(vec![kf("a", "s", 1, 0)]))
            .await
            .unwrap();
        let mut wrong = kf("a", "s", 2, 0);
        wrong.features.descriptor.push(0.0);
        // A batch with one bad keyframe stores none of it.
        let err = store
            .apply(Mutation::Insert(vec![kf("a", "s", 3, 0), wrong]))
            .await
            .unwrap_err();
        assert!(
            matches!(
                err,
                StoreError::DimensionMismatch {
                    expected: 3,
                    found: 4
                }
            ),
            "{err}"
        );
        assert_eq!(keys(&store).len(), 1);
    }
    assert!(matches!(
        open_when_free(dir.path(), 8),
        Err(StoreError::DimensionMismatch {
            expected: 3,
            found: 8
        })
    ));
    let store = reopen(dir.path(), 3);
    assert_eq!(store.index().dim(), 3);
}

#[tokio::test]
async fn concurrent_writers_are_all_committed() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), 0, 1024).unwrap();
    let tasks: Vec<_> = (0..200)
        .map(|i| {
            let store = store.clone();
            tokio::spawn(async move {
                store
                    .apply(Mutation::Insert(vec![kf("r", "s", i, 0)]))
                    .await
            })
        })
        .collect();
    for task in tasks {
        task.await.unwrap().unwrap();
    }
    drop(store);
    let store = reopen(dir.path(), 0);
    assert_eq!(store.index().len(), 200);
}

#[tokio::test]
async fn a_version_1_store_opens_upgraded_and_keeps_its_records() {
    let dir = tempfile::tempdir().unwrap();
    let old = kf("r", "s", 1, 0);
    {
        // What a version 1 build left: format 1 and a record without the
        // trailing thumbnail (its encoding ends in the empty Vec's 0 byte).
        let db = sled::open(dir.path()).unwrap();
        let meta = db.open_tree(META_TREE).unwrap();
        meta.insert(META_FORMAT, &1u32.to_be_bytes()).unwrap();
        let mut v1 = codec::encode_record(&old);
        assert_eq!(v1.pop(), Some(0));
        v1[0] = 1;
        db.open_tree(KEYFRAMES_TREE)
            .unwrap()
            .insert(codec::encode_key(&old.key), v1)
            .unwrap();
        db.flush().unwrap();
    }
    let store = reopen(dir.path(), 0);
    assert_eq!(store.index().keyframe(0), old);
    let mut new = kf("r", "s", 2, 0);
    new.features.appearance = vec![5; humem_core::vpr::appearance::LEN];
    store
        .apply(Mutation::Insert(vec![new.clone()]))
        .await
        .unwrap();
    drop(store);
    let store = reopen(dir.path(), 0);
    let row = store.index().row_of(&new.key).unwrap();
    assert_eq!(store.index().keyframe(row), new);
    let meta = store.db.open_tree(META_TREE).unwrap();
    assert_eq!(
        meta.get(META_FORMAT).unwrap().unwrap().as_ref(),
        &STORE_FORMAT.to_be_bytes()
    );
}

#[tokio::test]
async fn the_recorded_length_is_read_without_creating_a_store() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    assert_eq!(recorded_dim(&data).unwrap(), None);
    std::fs::create_dir(&data).unwrap();
    assert_eq!(recorded_dim(&data).unwrap(), None);
    assert_eq!(
        std::fs::read_dir(&data).unwrap().count(),
        0,
        "nothing created"
    );
    {
        let store = Store::open(&data, 0, 16).unwrap();
        store.flush().unwrap();
    }
    let read_when_free = || {
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
        loop {
            match recorded_dim(&data) {
                Err(StoreError::Open { .. }) if std::time::Instant::now() < deadline => {
                    std::thread::sleep(std::time::Duration::from_millis(20))
                }
                result => return result.unwrap(),
            }
        }
    };
    assert_eq!(read_when_free(), None, "no length fixed yet");
    {
        let store = reopen(&data, 0);
        store
            .apply(Mutation::Insert(vec![kf("a", "s", 1, 0)]))
            .await
            .unwrap();
        store.flush().unwrap();
    }
    assert_eq!(read_when_free(), Some(3));
}
