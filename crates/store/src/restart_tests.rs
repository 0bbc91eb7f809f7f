//! Restart tests: the index loaded from a snapshot and the journal is the
//! index rebuilt from the tree, after every kind of change, and a snapshot
//! that does not fit the store is never used.

use super::tests::{kf, open_retrying, open_when_free, session};
use super::*;
use humem_core::engine::filter::RowFilter;
use humem_core::keyframe::Pose;
use humem_core::vpr::eligibility::{QueryContext, Scope};
use std::time::{Duration, Instant};

/// Opens `dir` with automatic snapshots off, so each test decides when
/// one is written.
fn open_manual(dir: &Path) -> Store {
    open_manual_with(dir, None)
}

/// [`open_manual`], with the descriptors leaving memory from
/// `descriptors_to_file_from` keyframes.
fn open_manual_with(dir: &Path, descriptors_to_file_from: Option<usize>) -> Store {
    open_retrying(
        dir,
        StoreOptions {
            snapshot_every: 0,
            queue_capacity: 16,
            descriptors_to_file: descriptors_to_file_from.map(FileRule::from_keyframes),
            ..StoreOptions::default()
        },
    )
}

/// Every keyframe of the store, in key order, with its predecessor's key:
/// what a query can see.
fn contents(store: &Store) -> Vec<(SemanticKeyframe, Option<KeyframeKey>)> {
    let index = store.index();
    let mut all: Vec<_> = (0..index.len())
        .map(|row| {
            let prev = humem_core::vpr::memory::KeyframeMemory::predecessor(&*index, row)
                .map(|p| index.meta(p).key.clone());
            (index.keyframe(row), prev)
        })
        .collect();
    all.sort_by(|a, b| a.0.key.cmp(&b.0.key));
    all
}

/// What the tree alone says: the store reopened without its snapshot.
fn rebuilt_from_tree(dir: &Path) -> Vec<(SemanticKeyframe, Option<KeyframeKey>)> {
    let saved = dir.join("saved.snapshot");
    std::fs::rename(snapshot::path(dir), &saved).unwrap();
    let store = open_manual(dir);
    assert!(matches!(store.opened().source, IndexSource::Tree { .. }));
    let contents = contents(&store);
    drop(store);
    std::fs::rename(&saved, snapshot::path(dir)).unwrap();
    contents
}

async fn insert(store: &Store, keyframes: Vec<SemanticKeyframe>) {
    store.apply(Mutation::Insert(keyframes)).await.unwrap();
}

#[tokio::test]
async fn a_clean_restart_loads_the_snapshot_and_replays_nothing() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open_manual(dir.path());
        assert_eq!(
            store.opened().source,
            IndexSource::Tree {
                reason: "no snapshot".into()
            }
        );
        let mut batch: Vec<_> = (0..20).map(|i| kf("a", "s", i, i / 10)).collect();
        batch[3].features.appearance = vec![7; humem_core::vpr::appearance::LEN];
        insert(&store, batch).await;
        assert!(store.snapshot().unwrap().is_some());
        // Nothing changed since: no second snapshot.
        assert_eq!(store.snapshot().unwrap(), None);
    }
    let store = open_manual(dir.path());
    assert_eq!(store.opened().source, IndexSource::Snapshot { replayed: 0 });
    let loaded = contents(&store);
    drop(store);
    assert_eq!(loaded.len(), 20);
    assert_eq!(loaded, rebuilt_from_tree(dir.path()));
}

#[tokio::test]
async fn changes_after_the_snapshot_are_replayed_from_the_journal() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open_manual(dir.path());
        insert(&store, (0..30).map(|i| kf("a", "s", i, i / 10)).collect()).await;
        insert(&store, (0..5).map(|i| kf("b", "s", i, 0)).collect()).await;
        store.snapshot().unwrap();
        // Every kind of change after it, as a crash would leave them.
        insert(&store, vec![kf("a", "s", 30, 2), kf("c", "s", 0, 0)]).await;
        let mut replaced = kf("a", "s", 4, 0);
        replaced.features.descriptor = vec![0.5, 0.5, 0.5];
        insert(&store, vec![replaced]).await;
        let erase = Mutation::Erase {
            session: session("a", "s"),
            keyframe_ids: vec![1, 15, 15, 99],
        };
        assert_eq!(store.apply(erase).await.unwrap().affected, 2);
        let reset_map = Mutation::ResetMap(MapKey {
            session: session("a", "s"),
            map_id: 1,
        });
        store.apply(reset_map).await.unwrap();
        store
            .apply(Mutation::ResetSession(session("b", "s")))
            .await
            .unwrap();
        let moved = Mutation::UpdatePoses {
            session: session("a", "s"),
            updates: vec![PoseUpdate {
                keyframe_id: 22,
                pose: Pose::default(),
                map_id: Some(0),
            }],
        };
        store.apply(moved).await.unwrap();
        // Dropped without a snapshot, as a kill leaves it.
    }
    let store = open_manual(dir.path());
    let IndexSource::Snapshot { replayed } = store.opened().source else {
        panic!("not from the snapshot: {:?}", store.opened().source);
    };
    assert!(replayed >= 20, "replayed {replayed}");
    let loaded = contents(&store);
    drop(store);
    assert_eq!(loaded, rebuilt_from_tree(dir.path()));
    assert!(loaded.iter().all(|(kf, _)| kf.key.robot_id != "b"));
}

#[tokio::test]
async fn descriptors_in_a_file_keep_every_change_across_restarts() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open_manual_with(dir.path(), Some(10));
        insert(&store, (0..8).map(|i| kf("a", "s", i, 0)).collect()).await;
        assert!(store.index().descriptors_in_memory(), "below the threshold");
        insert(&store, (8..30).map(|i| kf("a", "s", i, i / 10)).collect()).await;
        assert!(
            !store.index().descriptors_in_memory(),
            "moved by the writer"
        );
        store.snapshot().unwrap();
        let mut replaced = kf("a", "s", 4, 0);
        replaced.features.descriptor = vec![0.5, 0.5, 0.5];
        insert(&store, vec![replaced]).await;
        let erase = Mutation::Erase {
            session: session("a", "s"),
            keyframe_ids: vec![0, 15, 29],
        };
        assert_eq!(store.apply(erase).await.unwrap().affected, 3);
        let row = store.index().row_of(&kf("a", "s", 4, 0).key).unwrap();
        assert_eq!(&*store.index().descriptor(row), &[0.5, 0.5, 0.5]);
    }
    // From the snapshot (streamed into a file) plus the journal, and from
    // the tree: the same keyframes as an index in memory holds.
    let store = open_manual_with(dir.path(), Some(10));
    assert!(matches!(
        store.opened().source,
        IndexSource::Snapshot { .. }
    ));
    assert!(!store.index().descriptors_in_memory());
    assert_eq!(contents(&store).len(), 27);
    // Changes to rows that still lie in the snapshot's file, and a new
    // snapshot renamed over that file while the index reads from it.
    let mut replaced = kf("a", "s", 1, 0);
    replaced.features.descriptor = vec![0.25, 0.5, 0.75];
    insert(&store, vec![replaced, kf("b", "s", 0, 0)]).await;
    let erase = Mutation::Erase {
        session: session("a", "s"),
        keyframe_ids: vec![2, 28],
    };
    assert_eq!(store.apply(erase).await.unwrap().affected, 2);
    assert!(store.snapshot().unwrap().is_some());
    insert(&store, vec![kf("b", "s", 1, 0)]).await;
    let loaded = contents(&store);
    drop(store);
    assert_eq!(loaded.len(), 27);
    assert_eq!(loaded, rebuilt_from_tree(dir.path()));
    let store = open_manual_with(dir.path(), Some(10));
    assert_eq!(store.opened().source, IndexSource::Snapshot { replayed: 1 });
    assert_eq!(contents(&store), loaded);
    drop(store);
    std::fs::remove_file(snapshot::path(dir.path())).unwrap();
    let store = open_manual_with(dir.path(), Some(10));
    assert!(matches!(store.opened().source, IndexSource::Tree { .. }));
    assert!(!store.index().descriptors_in_memory());
    assert_eq!(contents(&store), loaded);
}

#[tokio::test]
async fn a_damaged_snapshot_is_not_used() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open_manual(dir.path());
        insert(&store, (0..10).map(|i| kf("a", "s", i, 0)).collect()).await;
        store.snapshot().unwrap();
    }
    let path = snapshot::path(dir.path());
    let mut bytes = std::fs::read(&path).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    let store = open_manual(dir.path());
    let IndexSource::Tree { reason } = &store.opened().source else {
        panic!("used a damaged snapshot");
    };
    assert!(reason.contains("checksum"), "{reason}");
    assert_eq!(store.index().len(), 10);
}

#[tokio::test]
async fn another_stores_snapshot_is_not_used() {
    let (one, other) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    for (dir, n) in [(&one, 3), (&other, 7)] {
        let store = open_manual(dir.path());
        insert(&store, (0..n).map(|i| kf("a", "s", i, 0)).collect()).await;
        store.snapshot().unwrap();
    }
    std::fs::copy(snapshot::path(other.path()), snapshot::path(one.path())).unwrap();
    let store = open_when_free(one.path(), 0).unwrap();
    let IndexSource::Tree { reason } = &store.opened().source else {
        panic!("used another store's snapshot");
    };
    assert!(reason.contains("another store"), "{reason}");
    assert_eq!(store.index().len(), 3);
}

#[tokio::test]
async fn a_snapshot_older_than_the_journal_is_not_used() {
    let dir = tempfile::tempdir().unwrap();
    let old = dir.path().join("old.snapshot");
    {
        let store = open_manual(dir.path());
        insert(&store, vec![kf("a", "s", 0, 0)]).await;
        store.snapshot().unwrap();
        std::fs::copy(snapshot::path(dir.path()), &old).unwrap();
        insert(&store, vec![kf("a", "s", 1, 0)]).await;
        // The newer snapshot drops the journal entry the old one needs.
        store.snapshot().unwrap();
    }
    std::fs::rename(&old, snapshot::path(dir.path())).unwrap();
    let store = open_manual(dir.path());
    let IndexSource::Tree { reason } = &store.opened().source else {
        panic!("used a snapshot the journal cannot bring up to date");
    };
    assert!(reason.contains("older than the journal"), "{reason}");
    assert_eq!(store.index().len(), 2);
}

#[tokio::test]
async fn snapshots_follow_the_changes_and_bound_the_journal() {
    let dir = tempfile::tempdir().unwrap();
    let options = StoreOptions {
        snapshot_every: 50,
        ..StoreOptions::default()
    };
    let store = Store::open_with(dir.path(), options, humem_core::observe::unobserved()).unwrap();
    for i in 0..30 {
        insert(&store, (0..5).map(|j| kf("a", "s", i * 5 + j, 0)).collect()).await;
    }
    // 150 changes: at least two automatic snapshots, on their own thread.
    let deadline = Instant::now() + Duration::from_secs(10);
    while store
        .checkpoints
        .running
        .load(std::sync::atomic::Ordering::Acquire)
        || !snapshot::path(dir.path()).exists()
    {
        assert!(Instant::now() < deadline, "no snapshot was written");
        std::thread::sleep(Duration::from_millis(10));
    }
    let floor = journal::floor(&store.checkpoints.meta).unwrap();
    assert!(floor >= 10, "journal floor {floor}");
    let left = store.checkpoints.journal.len() as u64;
    assert!(
        left <= 30 - floor,
        "{left} entries left above floor {floor}"
    );
    drop(store);
    let store = open_manual(dir.path());
    assert!(matches!(
        store.opened().source,
        IndexSource::Snapshot { .. }
    ));
    assert_eq!(store.index().len(), 150);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_snapshot_taken_while_the_store_changes_loads_as_the_tree() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open_manual(dir.path());
        insert(&store, (0..60).map(|i| kf("a", "s", i, i / 20)).collect()).await;
        insert(&store, (0..20).map(|i| kf("b", "s", i, 0)).collect()).await;
        // Between chunks of 4 rows: removals (which move the last row into
        // the hole), replacements, inserts, resets and pose moves.
        let runtime = tokio::runtime::Handle::current();
        let changing = store.clone();
        let mut step = 0u64;
        let mut between = move || {
            step += 1;
            let mutation = match step % 5 {
                0 => Mutation::Erase {
                    session: session("a", "s"),
                    keyframe_ids: vec![step, step * 3 % 60],
                },
                1 => Mutation::Insert(vec![kf("c", "s", step, 0), kf("a", "s", step + 1, 1)]),
                2 => Mutation::Erase {
                    session: session("b", "s"),
                    keyframe_ids: vec![step % 20],
                },
                3 => Mutation::UpdatePoses {
                    session: session("a", "s"),
                    updates: vec![PoseUpdate {
                        keyframe_id: 59 - step % 60,
                        pose: Pose::default(),
                        map_id: Some(step % 3),
                    }],
                },
                _ => Mutation::ResetMap(MapKey {
                    session: session("c", "s"),
                    map_id: 0,
                }),
            };
            runtime.block_on(changing.apply(mutation)).unwrap();
        };
        let checkpoints = store.checkpoints.clone();
        let (unpublished, sequence) = tokio::task::spawn_blocking(move || {
            snapshot::write_in_chunks(
                &checkpoints.dir,
                checkpoints.store_id,
                &checkpoints.index,
                &checkpoints.applied,
                Some(4),
                &mut between,
            )
        })
        .await
        .unwrap()
        .unwrap();
        unpublished.publish().unwrap();
        assert!(sequence >= 2);
        assert!(
            store
                .checkpoints
                .applied
                .load(std::sync::atomic::Ordering::Acquire)
                > sequence + 10,
            "the store changed while the snapshot was written"
        );
    }
    let store = open_manual(dir.path());
    assert!(
        matches!(store.opened().source, IndexSource::Snapshot { .. }),
        "{:?}",
        store.opened().source
    );
    let loaded = contents(&store);
    drop(store);
    assert_eq!(loaded, rebuilt_from_tree(dir.path()));
}

/// Robot `r`'s keyframe `id`: map 0 for its first half, map 1 after.
fn fleet_keyframe(robot: usize, id: u64) -> SemanticKeyframe {
    kf(&format!("robot-{robot}"), "s", id, u64::from(id >= 700))
}

/// Opens the store in `dir` again: it loads from its snapshot, holds
/// `keyframes`, and holds what a rebuild from the tree holds.
fn reopens_from_its_snapshot_as_the_tree(dir: &Path, keyframes: usize) {
    let store = open_manual(dir);
    assert!(matches!(
        store.opened().source,
        IndexSource::Snapshot { .. }
    ));
    let loaded = contents(&store);
    assert_eq!(loaded.len(), keyframes);
    drop(store);
    assert_eq!(loaded, rebuilt_from_tree(dir));
}

#[tokio::test]
async fn rows_written_after_the_last_grouping_are_sorted_at_open() {
    use humem_core::index::GROUP_TAIL_ROWS;
    let dir = tempfile::tempdir().unwrap();
    // Fewer rows than a grouping takes, four robots interleaved, as a
    // fleet leaves them at a shutdown.
    let per_robot = (GROUP_TAIL_ROWS / 8) as u64;
    {
        let store = open_manual(dir.path());
        for id in 0..per_robot {
            insert(
                &store,
                (0..4).map(|robot| fleet_keyframe(robot, id)).collect(),
            )
            .await;
        }
        assert!(store.index().ungrouped_rows() > 0);
        store.snapshot().unwrap();
    }
    let store = open_manual(dir.path());
    // Sorted before the store took a request, not by its writer later.
    assert_eq!(store.index().window_due(), None);
    let index = store.index();
    let runs = 1
        + (1..index.len())
            .filter(|&row| index.meta(row - 1).key.robot_id != index.meta(row).key.robot_id)
            .count();
    assert_eq!(runs, 4, "one run of rows per robot");
    drop(index);
    drop(store);
    reopens_from_its_snapshot_as_the_tree(dir.path(), 4 * per_robot as usize);
}

#[tokio::test]
async fn the_writer_groups_a_fleets_newest_rows_by_map_and_a_reopen_finds_the_same_store() {
    use humem_core::index::GROUP_TAIL_ROWS;
    let dir = tempfile::tempdir().unwrap();
    let robots = 3;
    let per_robot = (GROUP_TAIL_ROWS / robots + 100) as u64;
    {
        let store = open_manual(dir.path());
        // Keyframes arrive interleaved, robot by robot, as a fleet's do.
        let all: Vec<SemanticKeyframe> = (0..per_robot)
            .flat_map(|id| (0..robots).map(move |robot| fleet_keyframe(robot, id)))
            .collect();
        for batch in all.chunks(97) {
            insert(&store, batch.to_vec()).await;
        }
        {
            let index = store.index();
            let ungrouped = index.ungrouped_rows();
            assert!(
                ungrouped < GROUP_TAIL_ROWS,
                "{ungrouped} rows left ungrouped"
            );
            let grouped = index.len() - ungrouped;
            assert!(grouped >= GROUP_TAIL_ROWS);
            // Among the grouped rows, each map is one run.
            let mut seen = std::collections::HashSet::new();
            for row in 0..grouped {
                let map = index.meta(row).map_key();
                if row == 0 || index.meta(row - 1).map_key() != map {
                    assert!(seen.insert(map.clone()), "{map:?} in two runs");
                }
            }
            assert_eq!(seen.len(), 2 * robots);
        }
        assert!(store.snapshot().unwrap().is_some());
    }
    reopens_from_its_snapshot_as_the_tree(dir.path(), robots * per_robot as usize);
}

#[tokio::test]
async fn a_snapshot_taken_while_the_rows_are_regrouped_fails_instead_of_missing_a_keyframe() {
    let dir = tempfile::tempdir().unwrap();
    let store = open_manual(dir.path());
    for id in 0..20 {
        insert(&store, vec![kf("a", "s", id, id % 2), kf("b", "s", id, 0)]).await;
    }
    assert_eq!(store.index().ungrouped_rows(), 40);
    let checkpoints = store.checkpoints.clone();
    let index = checkpoints.index.clone();
    let mut between = move || {
        index.write().group_tail();
    };
    let written = tokio::task::spawn_blocking(move || {
        snapshot::write_in_chunks(
            &checkpoints.dir,
            checkpoints.store_id,
            &checkpoints.index,
            &checkpoints.applied,
            Some(4),
            &mut between,
        )
    })
    .await
    .unwrap();
    assert!(
        matches!(written, Err(snapshot::SnapshotError::Regrouped)),
        "{:?}",
        written.map(|(_, sequence)| sequence)
    );
}

#[tokio::test]
async fn the_writer_sorts_again_rows_scattered_by_erasures_and_a_reopen_finds_the_same_store() {
    use humem_core::index::{GROUP_TAIL_ROWS, REGROUP_DISPLACED_ROWS};
    let dir = tempfile::tempdir().unwrap();
    let robots = 3;
    let per_robot = (GROUP_TAIL_ROWS / robots + 100) as u64;
    let erased = u64::from(REGROUP_DISPLACED_ROWS) + 20;
    let map_0 = MapKey {
        session: session("robot-0", "s"),
        map_id: 0,
    };
    // The runs robot 0's first map forms among the grouped rows.
    let runs_of_map_0 = |store: &Store| {
        let index = store.index();
        let grouped = index.len() - index.ungrouped_rows();
        let of_map = |row: usize| index.meta(row).map_key() == map_0;
        (0..grouped)
            .filter(|&row| of_map(row) && (row == 0 || !of_map(row - 1)))
            .count()
    };
    {
        let store = open_manual(dir.path());
        let all: Vec<SemanticKeyframe> = (0..per_robot)
            .flat_map(|id| (0..robots).map(move |robot| fleet_keyframe(robot, id)))
            .collect();
        for batch in all.chunks(97) {
            insert(&store, batch.to_vec()).await;
        }
        assert_eq!(runs_of_map_0(&store), 1);
        let epoch = store.index().layout_epoch();
        // Every other keyframe of robot 0's first map erased, one at a
        // time: each hole takes the store's last row, another map's.
        for id in 0..erased {
            let erase = Mutation::Erase {
                session: session("robot-0", "s"),
                keyframe_ids: vec![2 * id],
            };
            store.apply(erase).await.unwrap();
            if id + 1 == u64::from(REGROUP_DISPLACED_ROWS) - 1 {
                assert!(runs_of_map_0(&store) > 100, "scattered before it is due");
                assert_eq!(store.index().layout_epoch(), epoch, "nothing sorted yet");
            }
        }
        // The window was sorted again once it was due, and only the
        // erasures after that scatter it.
        assert!(store.index().layout_epoch() > epoch);
        assert!(runs_of_map_0(&store) <= 25, "{}", runs_of_map_0(&store));
        assert!(store.snapshot().unwrap().is_some());
    }
    reopens_from_its_snapshot_as_the_tree(
        dir.path(),
        robots * per_robot as usize - erased as usize,
    );
}

/// Opens `dir` keeping a neighbour graph, snapshots only when asked.
fn open_with_graph(dir: &Path) -> Store {
    open_retrying(
        dir,
        StoreOptions {
            snapshot_every: 0,
            queue_capacity: 16,
            neighbour_graph: true,
            ..StoreOptions::default()
        },
    )
}

/// The nearest keyframe to `descriptor` among those the graph proposes
/// (its own and those waiting to enter it), scored exactly as a query
/// scores them, by key.
fn nearest_key(store: &Store, descriptor: &[f32]) -> Option<KeyframeKey> {
    let index = store.index();
    let rows = index.nearest_rows(descriptor, 1, &|_| true)?;
    let score = |row: usize| humem_core::engine::matrix::dot(&index.descriptor(row), descriptor);
    let best = rows
        .into_iter()
        .max_by(|&a, &b| score(a).total_cmp(&score(b)))?;
    Some(index.meta(best).key.clone())
}

/// Keyframe `id` of robot a's session s in map 0, with `descriptor`.
fn with(id: u64, descriptor: [f32; 3]) -> SemanticKeyframe {
    let mut k = kf("a", "s", id, 0);
    k.features.descriptor = descriptor.to_vec();
    k
}

/// Replaces keyframe 5 of robot a's session s by a descriptor no other
/// has (`[0, 0, 1]`) and erases its keyframe 7.
async fn replace_5_and_erase_7(store: &Store) {
    insert(store, vec![with(5, [0.0, 0.0, 1.0])]).await;
    store
        .apply(Mutation::Erase {
            session: session("a", "s"),
            keyframe_ids: vec![7],
        })
        .await
        .unwrap();
}

#[tokio::test]
async fn the_neighbour_graph_is_saved_with_the_snapshot_and_replayed_changes_reach_it() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open_with_graph(dir.path());
        insert(
            &store,
            (0..30)
                .map(|i| with(i, [1.0, i as f32 * 0.1, 0.0]))
                .collect(),
        )
        .await;
        assert!(store.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
        assert_eq!(store.index().neighbour_graph().unwrap().len(), 30);
        store.snapshot().unwrap();
        assert!(graph_file::path(dir.path()).exists());
        // After the snapshot, in the journal only.
        replace_5_and_erase_7(&store).await;
    }
    let store = open_with_graph(dir.path());
    assert_eq!(store.opened().source, IndexSource::Snapshot { replayed: 2 });
    // Found at once, whether it has entered the graph yet or waits.
    assert_eq!(
        nearest_key(&store, &[0.0, 0.0, 1.0]),
        Some(session("a", "s").keyframe(5))
    );
    assert!(store.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
    let index = store.index();
    let graph = index.neighbour_graph().expect("a graph after the restart");
    assert_eq!(graph.len(), 29);
    assert_eq!(index.neighbour_graph_missing(), 0);
    drop(index);
    assert_eq!(
        nearest_key(&store, &[0.0, 0.0, 1.0]),
        Some(session("a", "s").keyframe(5))
    );
    let index = store.index();
    let rows = index.nearest_rows(&[1.0, 0.7, 0.0], 30, &|_| true).unwrap();
    assert_eq!(rows.len(), 29);
    assert!(rows.iter().all(|&r| index.meta(r).key.keyframe_id != 7));
}

#[tokio::test]
async fn a_store_without_a_saved_graph_builds_one_at_open() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open_manual(dir.path());
        insert(&store, (0..25).map(|i| kf("a", "s", i, 0)).collect()).await;
        assert!(store.index().neighbour_graph().is_none());
        store.snapshot().unwrap();
    }
    assert!(!graph_file::path(dir.path()).exists());
    let store = open_with_graph(dir.path());
    assert!(store.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
    assert_eq!(store.index().neighbour_graph().unwrap().len(), 25);
}

#[tokio::test]
async fn graphs_built_since_the_open_are_saved_where_the_snapshot_is_current() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open_manual(dir.path());
        insert(&store, (0..25).map(|i| kf("a", "s", i, 0)).collect()).await;
        store.snapshot().unwrap();
    }
    {
        let store = open_with_graph(dir.path());
        assert_eq!(store.opened().graph, Some(graph_file::GraphSource::Built));
        assert!(store.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
        // Nothing was written since the snapshot, so none is written (as
        // at a shutdown), but the graph built since the open is saved.
        assert!(store.snapshot().unwrap().is_none());
        assert!(graph_file::path(dir.path()).exists());
    }
    let store = open_with_graph(dir.path());
    assert_eq!(store.opened().graph, Some(graph_file::GraphSource::Loaded));
    assert_eq!(store.index().neighbour_graph_waiting(), 0);
    assert_eq!(store.index().neighbour_graph().unwrap().len(), 25);
}

#[tokio::test]
async fn a_snapshot_without_a_graph_removes_the_one_an_earlier_open_saved() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = open_with_graph(dir.path());
        insert(&store, (0..10).map(|i| kf("a", "s", i, 0)).collect()).await;
        store.snapshot().unwrap();
    }
    assert!(graph_file::path(dir.path()).exists());
    {
        let store = open_manual(dir.path());
        insert(&store, vec![kf("a", "s", 20, 0)]).await;
        store.snapshot().unwrap();
    }
    // It would lack the keyframe stored meanwhile.
    assert!(!graph_file::path(dir.path()).exists());
    let store = open_with_graph(dir.path());
    assert!(store.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
    assert_eq!(store.index().neighbour_graph().unwrap().len(), 11);
}

#[tokio::test]
async fn a_saved_graph_of_another_length_is_rebuilt_at_open() {
    let dir = tempfile::tempdir().unwrap();
    let open = |length: usize| {
        open_retrying(
            dir.path(),
            StoreOptions {
                snapshot_every: 0,
                queue_capacity: 16,
                neighbour_graph: true,
                neighbour_graph_length: length,
                ..StoreOptions::default()
            },
        )
    };
    {
        let store = open(4);
        let rows = (0..20u64)
            .map(|i| {
                let mut k = kf("a", "s", i, 0);
                k.features.descriptor = (0..8).map(|j| ((i * 8 + j) as f32 * 0.37).sin()).collect();
                k
            })
            .collect();
        insert(&store, rows).await;
        assert!(store.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
        assert_eq!(store.index().neighbour_graph().unwrap().stored_length(), 4);
        store.snapshot().unwrap();
    }
    {
        let store = open(4);
        assert_eq!(store.opened().graph, Some(graph_file::GraphSource::Loaded));
    }
    let store = open(0);
    assert_eq!(store.opened().graph, Some(graph_file::GraphSource::Built));
    assert!(store.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
    let index = store.index();
    let graph = index.neighbour_graph().unwrap();
    assert_eq!((graph.stored_length(), graph.len()), (8, 20));
}

#[tokio::test]
async fn large_maps_graphs_are_saved_with_the_snapshot_and_replayed_changes_reach_them() {
    let dir = tempfile::tempdir().unwrap();
    let open = || {
        open_retrying(
            dir.path(),
            StoreOptions {
                snapshot_every: 0,
                queue_capacity: 16,
                neighbour_graph: true,
                map_graphs_from: 10,
                ..StoreOptions::default()
            },
        )
    };
    {
        let store = open();
        assert_eq!(store.opened().map_graphs_loaded, 0);
        // Map 0 of robot a reaches the size, map 1 and robot b do not.
        let mut rows: Vec<_> = (0..12)
            .map(|i| with(i, [1.0, i as f32 * 0.1, 0.0]))
            .collect();
        rows.extend((12..15).map(|i| kf("a", "s", i, 1)));
        rows.extend((0..9).map(|i| kf("b", "s", i, 0)));
        insert(&store, rows).await;
        assert!(store.wait_for_neighbour_graph(Duration::from_secs(60)));
        assert_eq!(store.index().map_graphs().0, 1);
        assert_eq!(store.index().map_graphs().1, 12);
        store.snapshot().unwrap();
        let saved: Vec<_> = std::fs::read_dir(graph_file::maps_path(dir.path()))
            .unwrap()
            .collect();
        assert_eq!(saved.len(), 1, "one large map, one saved graph");
        // After the snapshot, in the journal only (both in the large map).
        replace_5_and_erase_7(&store).await;
    }
    let store = open();
    assert_eq!(store.opened().source, IndexSource::Snapshot { replayed: 2 });
    assert_eq!(store.opened().map_graphs_loaded, 1);
    assert!(store.wait_for_neighbour_graph(Duration::from_secs(60)));
    {
        let index = store.index();
        let map = index
            .eligibility(&QueryContext {
                session: session("a", "s"),
                keyframe_id: None,
                frame_id: 0,
                map_id: 0,
                min_frame_gap: 0,
                scope: Scope::SameMap,
                readable_robots: None,
            })
            .group()
            .expect("a loop query names one map");
        assert_eq!(index.map_graphs(), (1, 11, index.map_graphs().2));
        // The replaced keyframe is found by its new descriptor, the erased
        // one never.
        let rows = index
            .nearest_rows_of_map(&[0.0, 0.0, 1.0], 1, map, &|_| true)
            .unwrap();
        assert_eq!(index.meta(rows[0]).key, session("a", "s").keyframe(5));
        let rows = index
            .nearest_rows_of_map(&[1.0, 0.7, 0.0], 20, map, &|_| true)
            .unwrap();
        assert_eq!(rows.len(), 11);
        assert!(rows.iter().all(|&r| index.meta(r).key.keyframe_id != 7));
    }
    // A map that grows large later starts a graph of its own.
    insert(&store, vec![kf("b", "s", 9, 0)]).await;
    assert!(store.wait_for_neighbour_graph(Duration::from_secs(60)));
    assert_eq!(store.index().map_graphs().0, 2);
    assert_eq!(store.index().map_graphs().1, 21);
}
