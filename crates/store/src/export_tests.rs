//! An export restored into another directory is the same store: the same
//! keyframes, verdicts, descriptor length and log position; the target's
//! old contents are gone; damaged files are refused.

use super::tests::{kf, open_retrying, open_when_free, session};
use super::*;
use crate::graph_file::GraphSource;
use humem_core::verdict::{Verdict, VerificationKind};

fn held(store: &Store) -> (Vec<SemanticKeyframe>, usize, usize) {
    let index = store.index();
    let mut rows: Vec<_> = (0..index.len()).map(|row| index.keyframe(row)).collect();
    rows.sort_by(|a, b| a.key.cmp(&b.key));
    (rows, index.verdicts().len(), index.dim())
}

#[tokio::test]
async fn an_export_restores_the_same_store_elsewhere() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path(), 0, 16).unwrap();
    store
        .apply_log(vec![
            LogEntry {
                position: 3,
                mutation: Mutation::Insert((0..8).map(|i| kf("r", "s", i, i / 4)).collect()),
            },
            LogEntry {
                position: 4,
                mutation: Mutation::ReportVerdict(Verdict {
                    query: session("r", "s").keyframe(7),
                    candidate: session("r", "s").keyframe(1),
                    kind: VerificationKind::Loop,
                    accepted: false,
                    relative: None,
                    score: Some(0.4),
                    inliers: 3,
                    reported_at: 2.0,
                }),
            },
        ])
        .await
        .unwrap();
    let file = dir.path().join("export.bin");
    let header = store.export(&file).await.unwrap();
    assert_eq!(
        (
            header.log_position,
            header.keyframes,
            header.verdicts,
            header.dim
        ),
        (4, 8, 1, 3)
    );

    // Into a directory holding another store, which it replaces.
    let target = tempfile::tempdir().unwrap();
    {
        let other = Store::open(target.path(), 0, 16).unwrap();
        other
            .apply(Mutation::Insert(vec![kf("x", "y", 1, 0)]))
            .await
            .unwrap();
    }
    let restored_header = loop {
        match export::restore(target.path(), &file) {
            Err(StoreError::Open { .. }) => {
                std::thread::sleep(std::time::Duration::from_millis(20))
            }
            result => break result.unwrap(),
        }
    };
    assert_eq!(restored_header, header);
    assert_eq!(
        recorded_log(target.path()).unwrap(),
        RecordedLog {
            position: 4,
            holds_keyframes: true
        }
    );
    let restored = open_when_free(target.path(), 0).unwrap();
    assert_eq!(held(&restored), held(&store));
    assert_eq!(restored.log_position().unwrap(), 4);
    assert!(!target.path().join("restoring.tmp").exists());

    // A file cut short, or not an export, is refused.
    let bytes = std::fs::read(&file).unwrap();
    let cut = dir.path().join("cut.bin");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let elsewhere = tempfile::tempdir().unwrap();
    let refused = export::restore(elsewhere.path(), &cut).unwrap_err();
    assert!(refused.to_string().contains("cut short"), "{refused}");
    std::fs::write(&cut, b"something else entirely").unwrap();
    let refused = export::restore(elsewhere.path(), &cut).unwrap_err();
    assert!(
        refused.to_string().contains("not a HuMem store export"),
        "{refused}"
    );
}

#[tokio::test]
async fn an_export_that_would_eat_the_disk_reserve_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open_with(
        dir.path(),
        StoreOptions {
            // More than any disk has free: nothing may be written.
            min_free_bytes: u64::MAX / 4,
            ..StoreOptions::default()
        },
        humem_core::observe::unobserved(),
    )
    .unwrap();
    let file = dir.path().join("export.bin");
    let refused = store.export(&file).await.unwrap_err();
    assert!(matches!(refused, StoreError::DiskFull { .. }), "{refused}");
    assert!(!file.exists());
}

/// Opens `dir` keeping a neighbour graph, or not, once no other handle
/// holds it.
fn open_graph(dir: &std::path::Path, neighbour_graph: bool) -> Store {
    open_retrying(
        dir,
        StoreOptions {
            snapshot_every: 0,
            queue_capacity: 16,
            neighbour_graph,
            ..StoreOptions::default()
        },
    )
}

/// Restores `file` into a new directory, once no handle holds it.
fn restored_from(file: &std::path::Path) -> tempfile::TempDir {
    let target = tempfile::tempdir().unwrap();
    export::restore(target.path(), file).unwrap();
    target
}

#[tokio::test]
async fn an_export_carries_the_neighbour_graph_to_the_restored_store() {
    let dir = tempfile::tempdir().unwrap();
    let store = open_graph(dir.path(), true);
    let with = |id: u64, descriptor: [f32; 3]| {
        let mut k = kf("r", "s", id, 0);
        k.features.descriptor = descriptor.to_vec();
        k
    };
    store
        .apply(Mutation::Insert(
            (0..40)
                .map(|i| with(i, [1.0, i as f32 * 0.05, 0.0]))
                .collect(),
        ))
        .await
        .unwrap();
    // Replaced and erased after the inserts: the export's graph must
    // hold the replacement and not the erased row.
    store
        .apply(Mutation::Insert(vec![with(9, [0.0, 0.0, 1.0])]))
        .await
        .unwrap();
    store
        .apply(Mutation::Erase {
            session: session("r", "s"),
            keyframe_ids: vec![3],
        })
        .await
        .unwrap();
    let file = dir.path().join("export.bin");
    store.export(&file).await.unwrap();
    assert!(
        !dir.path().join("export.bin.graph").exists(),
        "the graph's own file is removed once exported"
    );

    let target = restored_from(&file);
    assert!(graph_file::restored_path(target.path()).exists());
    let restored = open_graph(target.path(), true);
    assert_eq!(restored.opened().graph, Some(GraphSource::Loaded));
    assert!(!graph_file::restored_path(target.path()).exists());
    assert!(restored.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
    let index = restored.index();
    assert_eq!(index.len(), 39);
    assert_eq!(index.neighbour_graph().unwrap().len(), 39);
    assert_eq!(index.neighbour_graph_missing(), 0);
    let nearest = index.nearest_rows(&[0.0, 0.0, 1.0], 1, &|_| true).unwrap();
    assert_eq!(index.meta(nearest[0]).key, session("r", "s").keyframe(9));
    let all = index.nearest_rows(&[1.0, 0.5, 0.0], 50, &|_| true).unwrap();
    assert_eq!(all.len(), 39);
    drop(index);
    drop(restored);

    // Opened again, the restored graph is not taken twice: the store's
    // own snapshot (or a build) provides it from then on.
    let again = open_graph(target.path(), true);
    assert!(again.opened().graph.is_some());
    assert!(again.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
    assert_eq!(again.index().neighbour_graph().unwrap().len(), 39);
    drop(again);

    // A store restored without a graph wanted drops the carried one.
    let other = restored_from(&file);
    let plain = open_graph(other.path(), false);
    assert!(plain.index().neighbour_graph().is_none());
    assert_eq!(plain.opened().graph, None);
    assert!(!graph_file::restored_path(other.path()).exists());
    assert!(!graph_file::path(other.path()).exists());
}

/// A store of 12 keyframes in `dir`, keeping a neighbour graph or not,
/// exported to `dir/export.bin`.
async fn exported_twelve(dir: &std::path::Path, neighbour_graph: bool) -> std::path::PathBuf {
    let store = open_graph(dir, neighbour_graph);
    store
        .apply(Mutation::Insert(
            (0..12).map(|i| kf("r", "s", i, 0)).collect(),
        ))
        .await
        .unwrap();
    let file = dir.join("export.bin");
    store.export(&file).await.unwrap();
    file
}

#[tokio::test]
async fn an_export_without_a_graph_restores_into_a_store_that_builds_one() {
    let dir = tempfile::tempdir().unwrap();
    let file = exported_twelve(dir.path(), false).await;
    let target = restored_from(&file);
    assert!(!graph_file::restored_path(target.path()).exists());
    let restored = open_graph(target.path(), true);
    assert_eq!(restored.opened().graph, Some(GraphSource::Built));
    assert!(restored.wait_for_neighbour_graph(std::time::Duration::from_secs(60)));
    assert_eq!(restored.index().neighbour_graph().unwrap().len(), 12);
}

#[tokio::test]
async fn a_graph_section_cut_short_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let file = exported_twelve(dir.path(), true).await;
    let bytes = std::fs::read(&file).unwrap();
    let cut = dir.path().join("cut.bin");
    std::fs::write(&cut, &bytes[..bytes.len() - 10]).unwrap();
    let elsewhere = tempfile::tempdir().unwrap();
    let refused = export::restore(elsewhere.path(), &cut).unwrap_err();
    assert!(refused.to_string().contains("cut short"), "{refused}");
}
