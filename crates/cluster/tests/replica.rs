//! The replica against a real `nats-server` (one node, JetStream, a stream
//! with one copy) and real sled stores: positions survive a restart, entries
//! that are not HuMem's are skipped alike, an entry from a newer build halts
//! the applier, and a store the stream can no longer bring up to date is
//! refused at start. Skipped, saying why, without `nats-server`.

use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::Duration;

use humem_cluster::{ClusterConfig, ClusterError, Replica, Unobserved};
use humem_core::keyframe::{Features, KeyframeKey, Pose, SemanticKeyframe, SessionKey};
use humem_store::{Mutation, Store};

struct Nats {
    child: Child,
    port: u16,
    _dir: tempfile::TempDir,
}

impl Drop for Nats {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn nats() -> Option<Nats> {
    if Command::new("nats-server")
        .arg("--version")
        .output()
        .is_err()
    {
        eprintln!(
            "skipped: nats-server is not installed (scripts/setup-system.sh test installs it)"
        );
        return None;
    }
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let dir = tempfile::tempdir().unwrap();
    let child = Command::new("nats-server")
        .args(["-a", "127.0.0.1", "-p", &port.to_string(), "-js", "-sd"])
        .arg(dir.path())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        std::thread::sleep(Duration::from_millis(20));
    }
    Some(Nats {
        child,
        port,
        _dir: dir,
    })
}

fn config(nats: &Nats) -> ClusterConfig {
    ClusterConfig {
        enabled: true,
        nats_urls: vec![format!("nats://127.0.0.1:{}", nats.port)],
        stream_replicas: 1,
        apply_timeout_ms: 3_000,
        ..ClusterConfig::default()
    }
}

fn keyframe(id: u64) -> SemanticKeyframe {
    SemanticKeyframe {
        key: KeyframeKey {
            robot_id: "r".into(),
            session_id: "s".into(),
            keyframe_id: id,
        },
        frame_id: id,
        timestamp: 0.0,
        map_id: 0,
        pose: Pose {
            translation: [0.0; 3],
            rotation: [1.0, 0.0, 0.0, 0.0],
        },
        features: Features {
            descriptor: vec![1.0, 0.0, id as f32],
            ..Features::default()
        },
    }
}

/// Opens a store once the previous handle's writer thread has let go of
/// the directory (sled holds a lock on it until then).
fn open(dir: &std::path::Path) -> Store {
    for _ in 0..250 {
        match Store::open(dir, 0, 64) {
            Ok(store) => return store,
            Err(humem_store::StoreError::Open { .. }) => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Err(e) => panic!("{e}"),
        }
    }
    panic!("the store in {} stayed locked", dir.display())
}

async fn start(nats: &Nats, dir: &std::path::Path) -> (Replica, Store) {
    let store = open(dir);
    let replica = Replica::start(config(nats), store.clone(), Arc::new(Unobserved))
        .await
        .unwrap();
    replica.catch_up().await.unwrap();
    (replica, store)
}

async fn publish_raw(nats: &Nats, headers: &[(&str, &str)], payload: &'static [u8]) {
    let client = async_nats::connect(format!("127.0.0.1:{}", nats.port))
        .await
        .unwrap();
    let mut map = async_nats::HeaderMap::new();
    for (k, v) in headers {
        map.insert(*k, *v);
    }
    let js = async_nats::jetstream::new(client);
    js.publish_with_headers("humem.writes", map, payload.into())
        .await
        .unwrap()
        .await
        .unwrap();
}

#[tokio::test(flavor = "multi_thread")]
async fn a_second_replica_and_a_restart_resume_from_their_positions() {
    let Some(nats) = nats() else { return };
    let (a_dir, b_dir) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let (a, _) = start(&nats, a_dir.path()).await;
    for id in 0..3 {
        let written = a.write(Mutation::Insert(vec![keyframe(id)])).await.unwrap();
        assert_eq!(written.sequence, id + 1);
        assert_eq!(written.outcome.store_keyframes, id + 1);
    }
    // A new replica catches up from the stream before it is ready.
    let (b, b_store) = start(&nats, b_dir.path()).await;
    assert_eq!(b.applied(), 3);
    assert_eq!(b_store.index().len(), 3);
    b.shutdown().await;
    drop((b, b_store));
    // Written while b is down; b resumes after entry 3, not from the start.
    let erased = a
        .write(Mutation::Erase {
            session: SessionKey {
                robot_id: "r".into(),
                session_id: "s".into(),
            },
            keyframe_ids: vec![0],
        })
        .await
        .unwrap();
    assert_eq!(erased.outcome.affected, 1);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let store = open(b_dir.path());
    assert_eq!(store.log_position().unwrap(), 3);
    drop(store);
    let (b, b_store) = start(&nats, b_dir.path()).await;
    assert_eq!(b.applied(), 4);
    assert_eq!(b_store.index().len(), 2);
    // A refusal (another descriptor length) is refused on every replica.
    let mut long = keyframe(9);
    long.features.descriptor = vec![1.0; 5];
    let err = b.write(Mutation::Insert(vec![long])).await.unwrap_err();
    assert!(
        matches!(err, ClusterError::Store(ref e) if e.is_refusal()),
        "{err}"
    );
    b.wait_for(5, None).await.unwrap();
    a.wait_for(5, None).await.unwrap();
}

#[tokio::test(flavor = "multi_thread")]
async fn strangers_are_skipped_and_newer_entries_halt() {
    let Some(nats) = nats() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (replica, store) = start(&nats, dir.path()).await;
    // Not a HuMem entry: every replica skips it alike and goes on.
    publish_raw(&nats, &[], b"hello").await;
    let written = replica
        .write(Mutation::Insert(vec![keyframe(1)]))
        .await
        .unwrap();
    assert_eq!(written.sequence, 2);
    assert_eq!(store.log_position().unwrap(), 2);
    // From a newer build: the applier stops there rather than skip it, and
    // the replica takes no more writes.
    publish_raw(&nats, &[("Humem-Log-Format", "99")], b"").await;
    for _ in 0..100 {
        if replica.halted().is_some() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(replica.halted().unwrap().contains("newer"));
    let err = replica
        .write(Mutation::Insert(vec![keyframe(2)]))
        .await
        .unwrap_err();
    assert!(matches!(err, ClusterError::Halted(_)), "{err}");
    assert_eq!(store.log_position().unwrap(), 2);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_store_the_stream_cannot_bring_up_to_date_is_refused() {
    let Some(nats) = nats() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (replica, store) = start(&nats, dir.path()).await;
    replica
        .write(Mutation::Insert(vec![keyframe(1)]))
        .await
        .unwrap();
    replica.shutdown().await;
    drop((replica, store));
    // The stream loses its entries (as by max_age): a new replica would
    // miss them.
    let client = async_nats::connect(format!("127.0.0.1:{}", nats.port))
        .await
        .unwrap();
    let js = async_nats::jetstream::new(client);
    js.get_stream("HUMEM_WRITES")
        .await
        .unwrap()
        .purge()
        .await
        .unwrap();
    publish_raw(&nats, &[], b"after the purge").await;
    let fresh = tempfile::tempdir().unwrap();
    let err = Replica::start(
        config(&nats),
        Store::open(fresh.path(), 0, 64).unwrap(),
        Arc::new(Unobserved),
    )
    .await
    .err()
    .unwrap();
    assert!(
        matches!(err, ClusterError::Diverged(ref m) if m.contains("seed")),
        "{err}"
    );
    // The stream deleted and made again: the old store is ahead of it.
    js.delete_stream("HUMEM_WRITES").await.unwrap();
    let err = Replica::start(config(&nats), open(dir.path()), Arc::new(Unobserved))
        .await
        .err()
        .unwrap();
    assert!(
        matches!(err, ClusterError::Diverged(ref m) if m.contains("deleted")),
        "{err}"
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn a_store_from_before_cluster_mode_is_published_into_an_empty_log() {
    let Some(nats) = nats() else { return };
    let old = tempfile::tempdir().unwrap();
    {
        let store = open(old.path());
        store
            .apply(Mutation::Insert((0..50).map(keyframe).collect()))
            .await
            .unwrap();
    }
    // Joining an empty stream: the 50 keyframes become 2 entries (32 + 18).
    let (a, a_store) = start(&nats, old.path()).await;
    assert_eq!(a.applied(), 2);
    assert_eq!(a_store.log_position().unwrap(), 2);
    assert_eq!(a_store.index().len(), 50);
    // A new replica gets them from the log.
    let fresh = tempfile::tempdir().unwrap();
    let (_b, b_store) = start(&nats, fresh.path()).await;
    assert_eq!(b_store.index().len(), 50);
    // Another store from before cluster mode cannot join a log that has
    // entries already.
    let other = tempfile::tempdir().unwrap();
    let store = open(other.path());
    store
        .apply(Mutation::Insert(vec![keyframe(99)]))
        .await
        .unwrap();
    let err = Replica::start(config(&nats), store, Arc::new(Unobserved))
        .await
        .err()
        .unwrap();
    assert!(
        matches!(err, ClusterError::Diverged(ref m) if m.contains("outside cluster mode")),
        "{err}"
    );
}
