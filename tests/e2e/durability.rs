//! Nothing acknowledged is lost: not across a clean restart, not when the
//! server is killed with SIGKILL right after acknowledging.

use humem_server::proto;

use crate::harness::Server;
use crate::scenes::{self, id, query_stored, World};

#[tokio::test(flavor = "multi_thread")]
async fn sigkill_after_acknowledged_inserts_loses_none() {
    let dir = tempfile::tempdir().unwrap();
    // Index snapshots every 64 changes, written while inserts go on: the
    // restart loads the newest and replays the journal after it.
    let snapshots = ["HUMEM_STORE__SNAPSHOT_EVERY=64"];
    let server = Server::start_with(dir.path(), &snapshots);
    let mut world = World::new(120, 4);
    let drive = scenes::loop_drive(&mut world, "r", "s", 0, 120, 80);

    // 200 concurrent single inserts: they are committed in groups.
    let mut tasks = Vec::new();
    for (kf, _) in drive.clone() {
        let mut client = server.client().await;
        tasks.push(tokio::spawn(async move {
            client
                .insert(proto::InsertRequest { keyframe: Some(kf) })
                .await
                .map(|_| ())
        }));
    }
    for task in tasks {
        task.await.unwrap().expect("insert acknowledged");
    }
    // Kill at once: the acknowledgements are all the client has.
    server.kill();

    let server = Server::start_with(dir.path(), &snapshots);
    let stats = server.stats().await;
    assert_eq!(stats.keyframes, 200);
    let exposition = server.scrape();
    assert!(
        Server::sample(&exposition, "humem_store_open_seconds{source=\"snapshot\"}").is_some(),
        "{exposition}"
    );
    assert_eq!(stats.descriptor_dim, scenes::DIM as u32);
    // And they are usable: a revisit still finds its place.
    let (kf, place) = &drive[150];
    let reply = server
        .client()
        .await
        .query(query_stored("r", "s", id(kf)))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(reply.candidates[0].keyframe_id, *place as u64);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_clean_restart_keeps_everything_and_exits_zero() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut world = World::new(50, 5);
    let drive = scenes::loop_drive(&mut world, "r", "s", 3, 50, 0);
    scenes::insert_all(
        &mut server.client().await,
        drive.iter().map(|(kf, _)| kf.clone()),
    )
    .await;
    let before = server.stats().await;
    let opened = |server: &Server, source: &str| {
        Server::sample(
            &server.scrape(),
            &format!("humem_store_open_seconds{{source=\"{source}\"}}"),
        )
    };
    assert!(
        opened(&server, "tree").is_some(),
        "a new store is built from its tree"
    );
    let server = server.restart();
    let after = server.stats().await;
    // The shutdown wrote an index snapshot, so the restart loads it and
    // replays nothing.
    assert!(opened(&server, "snapshot").is_some(), "{}", server.scrape());
    assert_eq!(
        Server::sample(&server.scrape(), "humem_store_open_replayed_keyframes"),
        Some(0.0)
    );
    assert_eq!(before.keyframes, 50);
    assert_eq!(after.keyframes, before.keyframes);
    assert_eq!(after.maps, before.maps);
    assert_eq!(after.format_version, 3);
}

/// A server with its descriptor model takes keyframes with precomputed
/// descriptors of another length into an empty store (the Python
/// quickstart sends 256 values to the default 1280-value model): started
/// again, it takes the store it wrote instead of refusing to start.
#[tokio::test(flavor = "multi_thread")]
async fn a_restart_takes_the_precomputed_descriptors_the_server_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with_models(dir.path());
    let mut world = World::new(20, 9);
    let drive = scenes::loop_drive(&mut world, "r", "s", 2, 20, 0);
    scenes::insert_all(
        &mut server.client().await,
        drive.iter().map(|(kf, _)| kf.clone()),
    )
    .await;
    let before = server.stats().await;
    assert_eq!(
        (before.keyframes, before.descriptor_dim),
        (drive.len() as u64, scenes::DIM as u32)
    );
    let server = server.restart();
    let after = server.stats().await;
    assert_eq!(
        (after.keyframes, after.descriptor_dim),
        (before.keyframes, before.descriptor_dim)
    );
    assert_eq!(after.maps, before.maps);
}
