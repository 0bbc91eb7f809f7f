//! Store snapshots in a JetStream object store, so that the write log can
//! be bounded: replicas publish their store now and then, and a new or
//! long-absent replica whose position the stream no longer reaches starts
//! from the newest snapshot and replays only the entries after it.
//!
//! One object, [`OBJECT`], in the bucket `<stream>_SNAPSHOTS` (on the same
//! NATS, with the stream's copies), holds the newest snapshot: a store
//! export ([`humem_store::export`]) with the log position it reflects in
//! the object's metadata. Any replica may publish one once it has applied
//! `cluster.snapshot_every` entries past the newest; the object store
//! replaces the older one, so the bucket holds one store's size.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use async_nats::jetstream::{self, object_store};
use tokio::sync::watch;

use humem_store::export::ExportHeader;
use humem_store::Store;

use crate::applier::Shared;
use crate::config::ClusterConfig;
use crate::error::ClusterError;

/// The object holding the newest snapshot.
pub const OBJECT: &str = "store";
/// Metadata key of the snapshot's log position.
const POSITION: &str = "log_position";
/// Where a snapshot is written before upload, and downloaded to before a
/// restore, inside the store's directory (a restore keeps names that start
/// with `restoring`).
const UPLOAD_FILE: &str = "snapshot-upload.tmp";
const DOWNLOAD_FILE: &str = "restoring.download";
/// How often the publisher looks whether a snapshot is due.
const CHECK_EVERY: Duration = Duration::from_millis(500);
/// The wait after a failed snapshot before the next try: an export holds
/// the writer, so a failing upload must not repeat it every check.
const RETRY_AFTER_FAILURE: Duration = Duration::from_secs(60);

/// The bucket name of `config`'s stream.
pub fn bucket(config: &ClusterConfig) -> String {
    format!("{}_SNAPSHOTS", config.stream)
}

/// The snapshot bucket, created when missing.
pub(crate) async fn open_bucket(
    js: &jetstream::Context,
    config: &ClusterConfig,
) -> Result<object_store::ObjectStore, ClusterError> {
    let name = bucket(config);
    match js.get_object_store(&name).await {
        Ok(store) => Ok(store),
        Err(_) => js
            .create_object_store(object_store::Config {
                bucket: name.clone(),
                description: Some("HuMem store snapshots".into()),
                num_replicas: config.stream_replicas,
                storage: jetstream::stream::StorageType::File,
                ..Default::default()
            })
            .await
            .map_err(|e| ClusterError::Nats(format!("snapshot bucket {name}: {e}"))),
    }
}

/// The log position of the newest snapshot (`None`: there is none).
pub(crate) async fn newest(
    bucket: &object_store::ObjectStore,
) -> Result<Option<u64>, ClusterError> {
    match bucket.info(OBJECT).await {
        Ok(info) if !info.deleted => Ok(info.metadata.get(POSITION).and_then(|p| p.parse().ok())),
        Ok(_) => Ok(None),
        Err(e) if e.kind() == object_store::InfoErrorKind::NotFound => Ok(None),
        Err(e) => Err(ClusterError::Nats(format!("snapshot {OBJECT}: {e}"))),
    }
}

/// Downloads the newest snapshot and makes the store in `dir` from it
/// (no store may be open on `dir`). Returns what it restored.
pub(crate) async fn restore(
    bucket: &object_store::ObjectStore,
    dir: &Path,
) -> Result<ExportHeader, ClusterError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| ClusterError::Config(format!("{}: {e}", dir.display())))?;
    let file = dir.join(DOWNLOAD_FILE);
    let mut object = bucket
        .get(OBJECT)
        .await
        .map_err(|e| ClusterError::Nats(format!("downloading snapshot {OBJECT}: {e}")))?;
    let mut out = tokio::fs::File::create(&file)
        .await
        .map_err(|e| ClusterError::Config(format!("{}: {e}", file.display())))?;
    tokio::io::copy(&mut object, &mut out)
        .await
        .map_err(|e| ClusterError::Nats(format!("downloading snapshot {OBJECT}: {e}")))?;
    drop(out);
    let target = dir.to_path_buf();
    let from = file.clone();
    let restored =
        tokio::task::spawn_blocking(move || humem_store::export::restore(&target, &from))
            .await
            .map_err(|e| ClusterError::Config(e.to_string()))?;
    let _ = std::fs::remove_file(&file);
    Ok(restored?)
}

/// Publishes a snapshot whenever this replica has applied `every` entries
/// past the newest one (any replica's), until `stop`.
pub(crate) async fn publish_loop(
    bucket: object_store::ObjectStore,
    store: Store,
    dir: PathBuf,
    every: u64,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    let mut newest_known: Option<u64> = None;
    let mut not_before = tokio::time::Instant::now();
    loop {
        tokio::select! {
            _ = tokio::time::sleep(CHECK_EVERY) => {}
            _ = stop.changed() => {}
        }
        if *stop.borrow() {
            return;
        }
        let applied = *shared.applied.borrow();
        if applied < newest_known.unwrap_or(0) + every || tokio::time::Instant::now() < not_before {
            continue;
        }
        // Another replica may have published one meanwhile.
        match newest(&bucket).await {
            Ok(found) => newest_known = found,
            Err(e) => {
                tracing::warn!(error = %e, "cannot read the newest store snapshot; trying later");
                not_before = tokio::time::Instant::now() + RETRY_AFTER_FAILURE;
                continue;
            }
        }
        if applied < newest_known.unwrap_or(0) + every {
            continue;
        }
        match publish(&bucket, &store, &dir).await {
            Ok(header) => {
                tracing::info!(
                    position = header.log_position,
                    keyframes = header.keyframes,
                    "store snapshot published"
                );
                newest_known = Some(header.log_position);
            }
            Err(e) => {
                tracing::warn!(error = %e, retry_s = RETRY_AFTER_FAILURE.as_secs(), "publishing a store snapshot failed; trying later");
                not_before = tokio::time::Instant::now() + RETRY_AFTER_FAILURE;
            }
        }
    }
}

/// Exports the store and uploads it as the newest snapshot.
async fn publish(
    bucket: &object_store::ObjectStore,
    store: &Store,
    dir: &Path,
) -> Result<ExportHeader, ClusterError> {
    let file = dir.join(UPLOAD_FILE);
    let header = store.export(&file).await?;
    let mut input = tokio::fs::File::open(&file)
        .await
        .map_err(|e| ClusterError::Config(format!("{}: {e}", file.display())))?;
    let meta = object_store::ObjectMetadata {
        name: OBJECT.into(),
        description: Some(format!(
            "HuMem store at log position {}: {} keyframes",
            header.log_position, header.keyframes
        )),
        metadata: [(POSITION.to_string(), header.log_position.to_string())].into(),
        ..Default::default()
    };
    let put = bucket.put(meta, &mut input).await;
    let _ = std::fs::remove_file(&file);
    put.map_err(|e| ClusterError::Nats(format!("uploading snapshot {OBJECT}: {e}")))?;
    Ok(header)
}

/// Before the store in `dir` is opened: where the write log no longer
/// holds the entries after its position (they aged out while it was away,
/// or it is new and the log's head has moved), makes it from the newest
/// snapshot, if that one reaches the log. Returns what was restored, or
/// `None` where nothing needed to be (or no snapshot could help: the
/// replica's start then says why).
pub async fn restore_if_behind(
    config: &ClusterConfig,
    dir: &Path,
    observer: Arc<dyn crate::observe::ClusterObserver>,
) -> Result<Option<ExportHeader>, ClusterError> {
    config.validate().map_err(ClusterError::Config)?;
    let recorded = humem_store::recorded_log(dir)?;
    let position = recorded.position;
    if position == 0 && recorded.holds_keyframes {
        // Written outside cluster mode: never replaced by a snapshot (the
        // replica's start says what to do with it).
        return Ok(None);
    }
    let client = crate::nats::connect(config, observer).await?;
    let mut js = jetstream::new(client);
    js.set_timeout(crate::nats::ATTEMPT_TIMEOUT);
    let mut stream = crate::nats::stream(&js, config).await?;
    let first = stream
        .info()
        .await
        .map_err(|e| ClusterError::Nats(format!("stream {}: {e}", config.stream)))?
        .state
        .first_sequence;
    if position + 1 >= first {
        return Ok(None);
    }
    let bucket = open_bucket(&js, config).await?;
    match newest(&bucket).await? {
        Some(snapshot) if snapshot + 1 >= first && snapshot > position => {
            tracing::info!(
                position,
                stream_first = first,
                snapshot,
                "the write log no longer holds this store's next entry; starting from the newest store snapshot"
            );
            let header = restore(&bucket, dir).await?;
            tracing::info!(
                position = header.log_position,
                keyframes = header.keyframes,
                "store restored from the snapshot"
            );
            Ok(Some(header))
        }
        _ => Ok(None),
    }
}
