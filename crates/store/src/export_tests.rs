//! An export restored into another directory is the same store: the same
//! keyframes, verdicts, descriptor length and log position; the target's
//! old contents are gone; damaged files are refused.

use super::tests::{kf, open_when_free, session};
use super::*;
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
