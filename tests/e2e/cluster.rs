//! Cluster mode end to end: real `nats-server` processes clustered on
//! loopback, several `humem serve` replicas on one stream. A write through
//! any replica reaches all of them; nothing acknowledged is lost when a
//! NATS node and a replica die while writes go on; replicas answer alike;
//! bad input never enters the log.

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use humem_server::proto;
use tonic::Code;

use crate::harness::Server;
use crate::nats::{self, NatsCluster};
use crate::scenes::{self, World};

/// Starts a replica on `dir` joined to `nats`'s stream (3 copies).
fn replica(nats: &NatsCluster, dir: &std::path::Path, name: &str) -> Server {
    replica_with(
        nats,
        dir,
        name,
        &["HUMEM_CLUSTER__STREAM_REPLICAS=3".into()],
    )
}

/// Starts a replica on `dir` joined to `nats`'s stream, with `extra`
/// settings (`KEY=VALUE`).
fn replica_with(nats: &NatsCluster, dir: &std::path::Path, name: &str, extra: &[String]) -> Server {
    let mut settings = vec![
        "HUMEM_CLUSTER__ENABLED=true".to_string(),
        format!("HUMEM_CLUSTER__NATS_URLS={}", nats.urls_setting()),
        format!("HUMEM_CLUSTER__REPLICA_NAME={name}"),
    ];
    settings.extend_from_slice(extra);
    let settings: Vec<&str> = settings.iter().map(String::as_str).collect();
    Server::start_with(dir, &settings)
}

/// Waits until `server` has applied the log up to `position`.
async fn wait_for_position(server: &Server, position: u64, within: Duration) -> Duration {
    let started = Instant::now();
    while server.stats().await.log_position < position {
        assert!(
            started.elapsed() < within,
            "replica stuck at {} < {position}",
            server.stats().await.log_position
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    started.elapsed()
}

/// A query's answer reduced to what must agree across replicas.
fn answer(reply: &proto::QueryResponse) -> Vec<(String, u64, u32, u32)> {
    reply
        .candidates
        .iter()
        .map(|c| {
            (
                c.robot_id.clone(),
                c.keyframe_id,
                c.score.to_bits(),
                c.evidence.as_ref().map_or(0, |e| e.raw_score.to_bits()),
            )
        })
        .collect()
}

async fn ask(
    server: &Server,
    robot: &str,
    keyframe: u64,
    at: u64,
) -> Result<proto::QueryResponse, tonic::Status> {
    ask_in(server, robot, keyframe, at, proto::Scope::Unspecified).await
}

/// [`ask`] over `scope`.
async fn ask_in(
    server: &Server,
    robot: &str,
    keyframe: u64,
    at: u64,
    scope: proto::Scope,
) -> Result<proto::QueryResponse, tonic::Status> {
    let mut request = scenes::query_stored(robot, "s", keyframe);
    request.scope = scope as i32;
    request.min_log_sequence = Some(at);
    request.threshold = Some(0.0);
    request.top_n = Some(5);
    request.min_frame_gap = Some(0);
    server
        .client()
        .await
        .query(request)
        .await
        .map(tonic::Response::into_inner)
}

#[tokio::test(flavor = "multi_thread")]
async fn writes_through_any_replica_reach_every_replica() {
    if !nats::available() {
        return;
    }
    let nats = NatsCluster::start(3);
    let dirs: Vec<_> = (0..3).map(|_| tempfile::tempdir().unwrap()).collect();
    let replicas: Vec<Server> = dirs
        .iter()
        .zip(["a", "b", "c"])
        .map(|(dir, name)| replica(&nats, dir.path(), name))
        .collect();
    let mut world = World::new(40, 11);
    let drive = scenes::loop_drive(&mut world, "r", "s", 0, 40, 20);

    // One keyframe at a time, through each replica in turn: the log
    // positions rise by one per write, whichever replica took it.
    let mut last = 0;
    for (k, (kf, _)) in drive.iter().enumerate() {
        let reply = replicas[k % 3]
            .client()
            .await
            .insert(proto::InsertRequest {
                keyframe: Some(kf.clone()),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(reply.log_sequence, last + 1, "keyframe {k}");
        last = reply.log_sequence;
    }
    // Read-your-writes on a replica that did not take the write: the query
    // waits for it, however far behind the replica is.
    let newest = scenes::id(&drive.last().unwrap().0);
    let mut answers = Vec::new();
    for server in &replicas {
        let reply = ask(server, "r", newest, last).await.unwrap();
        assert!(!reply.candidates.is_empty());
        answers.push(answer(&reply));
    }
    assert_eq!(answers[0], answers[1], "replicas a and b answer alike");
    assert_eq!(answers[0], answers[2], "replicas a and c answer alike");
    for server in &replicas {
        let stats = server.stats().await;
        assert_eq!(stats.keyframes, drive.len() as u64);
        assert_eq!(stats.log_position, last);
    }

    // A write through one replica is applied on the others within a
    // bounded lag.
    let (kf, _) = &drive[0];
    let mut moved = kf.clone();
    moved.keyframe_id = Some(1000);
    let reply = replicas[2]
        .client()
        .await
        .insert(proto::InsertRequest {
            keyframe: Some(moved),
        })
        .await
        .unwrap()
        .into_inner();
    for server in &replicas[..2] {
        let lag = wait_for_position(server, reply.log_sequence, Duration::from_secs(5)).await;
        eprintln!("applied on another replica {lag:?} after the acknowledgement");
    }
    last = reply.log_sequence;

    // Bad input is refused before anything is published: the next valid
    // write takes the very next position.
    let mut nameless = kf.clone();
    nameless.robot_id.clear();
    let mut short = kf.clone();
    if let Some(proto::keyframe::Content::Features(f)) = &mut short.content {
        f.global_descriptor.truncate(3);
    }
    for bad in [nameless, short] {
        let status = replicas[1]
            .client()
            .await
            .insert(proto::InsertRequest {
                keyframe: Some(bad),
            })
            .await
            .unwrap_err();
        assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
    }
    let reply = replicas[1]
        .client()
        .await
        .erase(proto::EraseRequest {
            robot_id: "r".into(),
            session_id: "s".into(),
            keyframe_ids: vec![1000],
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(reply.erased, 1);
    assert_eq!(
        reply.log_sequence,
        last + 1,
        "nothing invalid entered the log"
    );

    // A verdict through one replica arrives on every replica, through the
    // log; one naming a keyframe no replica stores is refused alike.
    let verdict = |candidate: u64| proto::ReportVerificationRequest {
        robot_id: "r".into(),
        session_id: "s".into(),
        keyframe_id: Some(newest),
        candidate: Some(proto::KeyframeRef {
            robot_id: "r".into(),
            session_id: "s".into(),
            keyframe_id: Some(candidate),
        }),
        kind: proto::VerificationKind::Loop as i32,
        outcome: proto::VerificationOutcome::Rejected as i32,
        ..Default::default()
    };
    let reply = replicas[0]
        .client()
        .await
        .report_verification(verdict(3))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(reply.log_sequence, last + 2);
    for server in &replicas {
        wait_for_position(server, reply.log_sequence, Duration::from_secs(5)).await;
        assert_eq!(server.stats().await.verdicts, 1);
    }
    let status = replicas[1]
        .client()
        .await
        .report_verification(verdict(5000))
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::NotFound, "{status:?}");
    for server in &replicas {
        assert_eq!(server.stats().await.verdicts, 1);
    }

    // A position no replica has reached: UNAVAILABLE within the deadline.
    let mut request = scenes::query_stored("r", "s", newest);
    request.min_log_sequence = Some(1_000_000);
    let mut request = tonic::Request::new(request);
    request.set_timeout(Duration::from_millis(300));
    let status = replicas[0].client().await.query(request).await.unwrap_err();
    assert_eq!(status.code(), Code::Unavailable, "{status:?}");
    assert!(status.message().contains("1000000"), "{status:?}");
}

/// What one writer got acknowledged.
#[derive(Default)]
struct Acked {
    keyframes: Vec<u64>,
    positions: Vec<u64>,
    failures: usize,
    /// The longest time without an acknowledgement, failures included.
    longest_gap: Duration,
}

#[tokio::test(flavor = "multi_thread")]
async fn no_acknowledged_write_is_lost_when_a_nats_node_and_a_replica_die() {
    if !nats::available() {
        return;
    }
    let mut nats = NatsCluster::start(3);
    let dir_a = tempfile::tempdir().unwrap();
    let dir_b = tempfile::tempdir().unwrap();
    let a = replica(&nats, dir_a.path(), "a");
    let b = replica(&nats, dir_b.path(), "b");
    let urls = Arc::new(parking_lot::Mutex::new(vec![a.url.clone(), b.url.clone()]));
    let stop = Arc::new(AtomicBool::new(false));
    let mut world = World::new(50, 5);

    // Four robots write one keyframe at a time (about 20 a second each),
    // two through each replica;
    // a writer whose replica fails moves to the other, as a client behind
    // a load balancer would.
    let mut writers = Vec::new();
    for w in 0..4usize {
        let views: Vec<_> = (0..2000)
            .map(|k| scenes::features(world.view(k % 50, 0.3), 0, vec![]))
            .collect();
        let urls = urls.clone();
        let stop = stop.clone();
        writers.push(tokio::spawn(async move {
            let robot = format!("w{w}");
            let mut acked = Acked::default();
            let mut target = w % 2;
            let mut last_ack = Instant::now();
            for (k, features) in views.into_iter().enumerate() {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                let url = urls.lock()[target].clone();
                let kf = scenes::keyframe(&robot, "s", [k as u64, 3 * k as u64, 0], features);
                let sent = async {
                    let mut client =
                        humem_server::proto::place_recognition_client::PlaceRecognitionClient::connect(url)
                            .await
                            .map_err(|e| tonic::Status::unavailable(e.to_string()))?;
                    client
                        .insert(proto::InsertRequest { keyframe: Some(kf) })
                        .await
                };
                match tokio::time::timeout(Duration::from_secs(15), sent).await {
                    Ok(Ok(reply)) => {
                        acked.keyframes.push(k as u64);
                        acked.positions.push(reply.into_inner().log_sequence);
                        acked.longest_gap = acked.longest_gap.max(last_ack.elapsed());
                        last_ack = Instant::now();
                        // About 20 writes a second per robot.
                        tokio::time::sleep(Duration::from_millis(40)).await;
                    }
                    _ => {
                        acked.failures += 1;
                        target = 1 - target;
                        tokio::time::sleep(Duration::from_millis(50)).await;
                    }
                }
            }
            acked
        }));
    }

    // The node leading the stream's copies: its loss makes JetStream elect
    // another, and writes wait that out (publish retries with the same id).
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let leader = nats
        .stream_leader("HUMEM_WRITES")
        .expect("a node leads the stream");
    nats.kill_node(leader);
    b.kill();
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let b = replica(&nats, dir_b.path(), "b");
    urls.lock()[1] = b.url.clone();
    nats.start_node(leader);
    // Long enough for writes to go on after JetStream's election (4-9 s).
    tokio::time::sleep(Duration::from_millis(6000)).await;
    stop.store(true, Ordering::Relaxed);

    let mut acked = Vec::new();
    for writer in writers {
        acked.push(writer.await.unwrap());
    }
    let newest = acked
        .iter()
        .flat_map(|a| a.positions.iter().copied())
        .max()
        .unwrap();
    // Entries published but not acknowledged (a reply lost to the kills)
    // may lie beyond the newest acknowledged one: both replicas must reach
    // the end of the log.
    for server in [&a, &b] {
        wait_for_position(server, newest, Duration::from_secs(30)).await;
    }
    let end = a
        .stats()
        .await
        .log_position
        .max(b.stats().await.log_position);
    for server in [&a, &b] {
        wait_for_position(server, end, Duration::from_secs(30)).await;
    }
    let (sa, sb) = (a.stats().await, b.stats().await);
    assert_eq!(sa.keyframes, sb.keyframes);
    assert_eq!(sa.maps, sb.maps);
    let mut lost = 0;
    let mut checked = 0;
    for (w, writer) in acked.iter().enumerate() {
        let robot = format!("w{w}");
        let distinct: BTreeSet<_> = writer.keyframes.iter().collect();
        assert!(
            distinct.len() > 5,
            "writer {w} got {} acknowledgements",
            distinct.len()
        );
        for &k in &distinct {
            for server in [&a, &b] {
                match ask(server, &robot, *k, newest).await {
                    Ok(_) => checked += 1,
                    Err(status) if status.code() == Code::NotFound => lost += 1,
                    Err(status) => panic!("{status:?}"),
                }
            }
        }
        // The same answers on both replicas.
        for &k in distinct.iter().step_by(7) {
            let on_a = answer(&ask(&a, &robot, *k, newest).await.unwrap());
            let on_b = answer(&ask(&b, &robot, *k, newest).await.unwrap());
            assert_eq!(on_a, on_b, "robot {robot} keyframe {k}");
        }
    }
    eprintln!(
        "acknowledged {} writes ({} lookups on 2 replicas), {} failed attempts, longest wait for an acknowledgement {:?}, lost {lost}",
        acked.iter().map(|a| a.keyframes.len()).sum::<usize>(),
        checked,
        acked.iter().map(|a| a.failures).sum::<usize>(),
        acked.iter().map(|a| a.longest_gap).max().unwrap(),
    );
    assert_eq!(lost, 0, "acknowledged writes lost");
}

/// Runs `humem serve` with `settings` until it exits (it must, within 30 s)
/// and returns its exit status and what it printed on stderr.
fn serve_until_exit(dir: &std::path::Path, settings: &[String]) -> (bool, String) {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_humem"));
    command
        .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(dir)
        .env("HUMEM_PERCEPTION__ENABLED", "false")
        .env("HUMEM_METRICS__ENABLED", "false")
        .env("RUST_LOG", "error")
        .env("RUST_BACKTRACE", "0")
        .env_remove("HUMEM_CONFIG")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped());
    for setting in settings {
        let (key, value) = setting.split_once('=').unwrap();
        command.env(key, value);
    }
    let mut child = command.spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > deadline {
            child.kill().unwrap();
            let mut stderr = String::new();
            std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
            panic!("humem serve did not stop within 30 s: {stderr}");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    (status.success(), stderr)
}

#[tokio::test(flavor = "multi_thread")]
async fn nats_connections_use_tls_and_credentials() {
    if !nats::available() {
        return;
    }
    let pki = tempfile::tempdir().unwrap();
    let ca = crate::pki::Authority::new("nats test CA");
    let ca_file = ca.write_ca(pki.path(), "ca");
    let (cert, key) = ca.issue(pki.path(), "nats", &["localhost"]);
    let password = pki.path().join("password");
    std::fs::write(&password, "correct horse\n").unwrap();
    let config = format!(
        "tls {{\n  cert_file: {cert:?}\n  key_file: {key:?}\n}}\nauthorization {{\n  users = [ {{ user: humem, password: \"correct horse\" }} ]\n}}\n"
    );
    let nats = NatsCluster::start_with(1, Some(&config));
    let urls = nats.urls_setting_as("tls", "localhost");
    let base = |password_file: &std::path::Path| {
        vec![
            "HUMEM_CLUSTER__ENABLED=true".to_string(),
            format!("HUMEM_CLUSTER__NATS_URLS={urls}"),
            "HUMEM_CLUSTER__STREAM_REPLICAS=1".to_string(),
            format!("HUMEM_CLUSTER__TLS__CA={}", ca_file.display()),
            "HUMEM_CLUSTER__AUTH__USER=humem".to_string(),
            format!(
                "HUMEM_CLUSTER__AUTH__PASSWORD_FILE={}",
                password_file.display()
            ),
        ]
    };

    // The right CA and password: writes go through the log.
    let dir = tempfile::tempdir().unwrap();
    let settings = base(&password);
    let settings: Vec<&str> = settings.iter().map(String::as_str).collect();
    let server = Server::start_with(dir.path(), &settings);
    let mut world = World::new(4, 3);
    let kf = scenes::keyframe(
        "r",
        "s",
        [1, 3, 0],
        scenes::features(world.view(0, 0.1), 0, vec![]),
    );
    let reply = insert_reply(&server, kf).await;
    assert_eq!(reply.log_sequence, 1);
    drop(server);

    // A wrong password is refused at once, with the reason.
    let wrong = pki.path().join("wrong");
    std::fs::write(&wrong, "battery staple").unwrap();
    let (ok, stderr) = serve_until_exit(tempfile::tempdir().unwrap().path(), &base(&wrong));
    assert!(!ok);
    assert!(stderr.contains("cluster.auth"), "{stderr}");

    // Without the CA, the server's certificate is not trusted.
    let mut untrusting = base(&password);
    untrusting.retain(|s| !s.starts_with("HUMEM_CLUSTER__TLS__CA"));
    untrusting.push("HUMEM_CLUSTER__TLS__CA=/dev/null".into());
    let (ok, stderr) = serve_until_exit(tempfile::tempdir().unwrap().path(), &untrusting);
    assert!(!ok);
    assert!(stderr.contains("NATS"), "{stderr}");

    // NATS elsewhere without TLS or credentials: refused before connecting.
    let (ok, stderr) = serve_until_exit(
        tempfile::tempdir().unwrap().path(),
        &[
            "HUMEM_CLUSTER__ENABLED=true".to_string(),
            "HUMEM_CLUSTER__NATS_URLS=[\"nats://10.255.0.1:4222\"]".to_string(),
        ],
    );
    assert!(!ok);
    assert!(stderr.contains("refusing to reach NATS"), "{stderr}");
}

/// A replica whose applier halted (here on an entry from a newer build)
/// refuses queries with UNAVAILABLE and the reason; one configured with
/// `cluster.serve_stale_reads` goes on answering from its store.
#[tokio::test(flavor = "multi_thread")]
async fn a_halted_replica_refuses_queries_unless_told_to_serve_stale_reads() {
    if !nats::available() {
        return;
    }
    let nats = NatsCluster::start(1);
    let dirs: Vec<_> = (0..2).map(|_| tempfile::tempdir().unwrap()).collect();
    let start = |dir: &std::path::Path, name: &str, stale: bool| {
        replica_with(
            &nats,
            dir,
            name,
            &[
                "HUMEM_CLUSTER__STREAM_REPLICAS=1".into(),
                format!("HUMEM_CLUSTER__SERVE_STALE_READS={stale}"),
            ],
        )
    };
    let strict = start(dirs[0].path(), "strict", false);
    let stale = start(dirs[1].path(), "stale", true);
    let mut world = World::new(10, 3);
    let drive = scenes::loop_drive(&mut world, "r", "s", 0, 10, 5);
    let mut last = 0;
    for (kf, _) in &drive {
        last = insert_one(&strict, kf).await;
    }
    let newest = scenes::id(&drive.last().unwrap().0);
    for server in [&strict, &stale] {
        ask(server, "r", newest, last).await.unwrap();
    }

    // An entry in a format from the future: both appliers halt on it.
    nats::publish_raw(
        nats.client_port(0),
        "humem.writes",
        ("Humem-Log-Format", "999"),
        b"from a newer humem",
    );
    let started = Instant::now();
    let refused = loop {
        match ask(&strict, "r", newest, 0).await {
            Err(status) => break status,
            Ok(_) => {
                assert!(
                    started.elapsed() < Duration::from_secs(20),
                    "the strict replica still answers 20 s after the entry"
                );
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
    };
    assert_eq!(refused.code(), Code::Unavailable, "{refused:?}");
    assert!(
        refused
            .message()
            .contains("this replica stopped applying the write log"),
        "{refused:?}"
    );
    assert!(refused.message().contains("999"), "{refused:?}");
    // The other has halted too (its readiness says so), and answers all
    // the same, as configured.
    let answered = ask(&stale, "r", newest, 0).await.unwrap();
    assert!(!answered.candidates.is_empty());
}

/// `perception.reuse` on two replicas: a session reset through one keeps
/// the other from carrying the session's last read (of keyframes now
/// erased) into the session's next keyframe.
#[tokio::test(flavor = "multi_thread")]
async fn a_reset_through_another_replica_ends_the_read_a_session_carries() {
    if !nats::available() {
        return;
    }
    let nats = NatsCluster::start(1);
    let (dir_a, dir_b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let reuse: Vec<String> = [
        "HUMEM_CLUSTER__STREAM_REPLICAS=1",
        "HUMEM_PERCEPTION__ENABLED=true",
        "HUMEM_PERCEPTION__REUSE__MAX_CARRIED=2",
        "HUMEM_PERCEPTION__REUSE__MIN_SIMILARITY=0.9",
    ]
    .map(String::from)
    .into();
    let a = replica_with(&nats, dir_a.path(), "a", &reuse);
    let b = replica_with(&nats, dir_b.path(), "b", &reuse);
    let board = crate::images::rendered_text(&["EXIT 42", "MAIN ST"]);
    // Whether inserting keyframe `id` of robot r's session s through `a`
    // read its image (ran the text detector) instead of carrying a read.
    let read_on_a = |id: u64| {
        let board = board.clone();
        let a = &a;
        async move {
            let kf = crate::images::keyframe("r", id, crate::images::image(board));
            let reply = insert_reply(a, kf).await;
            reply.timings.iter().any(|t| t.stage == "ocr_det")
        }
    };
    assert!(read_on_a(1).await, "nothing to carry yet");
    assert!(!read_on_a(2).await, "the same view is carried");

    b.client()
        .await
        .reset_session(proto::ResetSessionRequest {
            robot_id: "r".into(),
            session_id: "s".into(),
        })
        .await
        .unwrap();
    let position = b.stats().await.log_position;
    wait_for_position(&a, position, Duration::from_secs(30)).await;
    assert_eq!(a.stats().await.keyframes, 0, "the reset reached replica a");
    // max_carried = 2 would carry this one too: the reset made through b
    // ended the read on a.
    assert!(read_on_a(3).await, "a read of erased keyframes was carried");
}

#[tokio::test(flavor = "multi_thread")]
async fn a_keyframe_quota_holds_when_three_replicas_take_writes_at_once() {
    if !nats::available() {
        return;
    }
    const QUOTA: u64 = 20;
    const WRITES: usize = 45;
    let nats = NatsCluster::start(3);
    let dirs: Vec<_> = (0..3).map(|_| tempfile::tempdir().unwrap()).collect();
    let settings = [
        "HUMEM_CLUSTER__STREAM_REPLICAS=3".to_string(),
        format!("HUMEM_QUOTAS__MAX_KEYFRAMES_PER_ROBOT={QUOTA}"),
    ];
    let replicas: Vec<Server> = dirs
        .iter()
        .zip(["a", "b", "c"])
        .map(|(dir, name)| replica_with(&nats, dir.path(), name, &settings))
        .collect();
    let mut world = World::new(WRITES, 13);
    let drive = scenes::loop_drive(&mut world, "r", "s", 0, WRITES, 0);

    // Every new keyframe of one robot at once, a third through each
    // replica: each replica's own index is empty when it takes its writes,
    // so only a check in the log's order can hold the quota.
    let mut writes = tokio::task::JoinSet::new();
    for (k, (kf, _)) in drive.iter().enumerate() {
        let mut client = replicas[k % 3].client().await;
        let request = proto::InsertRequest {
            keyframe: Some(kf.clone()),
        };
        let id = scenes::id(kf);
        writes.spawn(async move { (id, client.insert(request).await) });
    }
    let (mut stored, mut refused, mut last) = (BTreeSet::new(), BTreeSet::new(), 0);
    while let Some(result) = writes.join_next().await {
        let (id, result) = result.unwrap();
        match result {
            Ok(reply) => {
                stored.insert(id);
                last = last.max(reply.into_inner().log_sequence);
            }
            Err(status) if status.code() == Code::ResourceExhausted => {
                assert!(
                    status.message().contains(&format!("its quota is {QUOTA}")),
                    "{status:?}"
                );
                refused.insert(id);
            }
            Err(status) => panic!("an insert failed otherwise: {status:?}"),
        }
    }
    assert_eq!(
        (stored.len() as u64, refused.len() as u64),
        (QUOTA, WRITES as u64 - QUOTA)
    );
    // Every replica holds exactly the quota, the same keyframes.
    let mut held = Vec::new();
    for server in &replicas {
        wait_for_position(server, last, Duration::from_secs(20)).await;
        let stats = server.stats().await;
        assert_eq!(stats.keyframes, QUOTA, "{stats:?}");
        held.push(stats.maps);
    }
    assert!(held.windows(2).all(|w| w[0] == w[1]), "{held:?}");
    // A replacement adds nothing and passes; one more new keyframe does not.
    let keyframe = |id: u64| {
        let kf = drive.iter().find(|(kf, _)| scenes::id(kf) == id).unwrap();
        proto::InsertRequest {
            keyframe: Some(kf.0.clone()),
        }
    };
    let first_stored = *stored.first().unwrap();
    let first_refused = *refused.first().unwrap();
    replicas[1]
        .client()
        .await
        .insert(keyframe(first_stored))
        .await
        .unwrap();
    let status = replicas[2]
        .client()
        .await
        .insert(keyframe(first_refused))
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::ResourceExhausted, "{status:?}");
}

/// Inserts one keyframe through `server`; returns its log position.
async fn insert_one(server: &Server, kf: &proto::Keyframe) -> u64 {
    insert_reply(server, kf.clone()).await.log_sequence
}

/// Inserts `kf` through `server`; its reply.
async fn insert_reply(server: &Server, kf: proto::Keyframe) -> proto::InsertResponse {
    server
        .client()
        .await
        .insert(proto::InsertRequest { keyframe: Some(kf) })
        .await
        .unwrap()
        .into_inner()
}

/// The log position of the newest store snapshot in `nats`'s bucket.
async fn snapshot_position(js: &async_nats::jetstream::Context) -> Option<u64> {
    let bucket = js.get_object_store("HUMEM_WRITES_SNAPSHOTS").await.ok()?;
    let info = bucket.info("store").await.ok()?;
    info.metadata.get("log_position")?.parse().ok()
}

#[tokio::test(flavor = "multi_thread")]
async fn a_new_replica_starts_from_the_snapshot_once_the_log_has_moved_past_it() {
    if !nats::available() {
        return;
    }
    let nats = NatsCluster::start(1);
    let dirs: Vec<_> = (0..2).map(|_| tempfile::tempdir().unwrap()).collect();
    // Every query goes through the neighbour graph, which the snapshot
    // carries to the new replica.
    let settings = |every: u64| {
        [
            "HUMEM_CLUSTER__STREAM_REPLICAS=1".to_string(),
            format!("HUMEM_CLUSTER__SNAPSHOT_EVERY={every}"),
            "HUMEM_VPR__APPROXIMATE_FROM=1".to_string(),
        ]
    };
    let first = replica_with(&nats, dirs[0].path(), "first", &settings(10));
    let mut world = World::new(30, 17);
    let drive = scenes::loop_drive(&mut world, "r", "s", 0, 30, 10);
    let mut last = 0;
    for (kf, _) in &drive[..25] {
        last = insert_one(&first, kf).await;
    }
    let client = async_nats::connect(format!("nats://127.0.0.1:{}", nats.client_port(0)))
        .await
        .unwrap();
    let js = async_nats::jetstream::new(client);
    let started = Instant::now();
    let snapshot = loop {
        match snapshot_position(&js).await {
            Some(position) if position >= 20 => break position,
            _ => {
                assert!(
                    started.elapsed() < Duration::from_secs(20),
                    "no snapshot at 20 entries or more"
                );
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    };
    // The log's head moves past every position a new replica could start
    // from, as retention does (here at once): entries up to the snapshot's
    // go, and more writes follow.
    let mut stream = js.get_stream("HUMEM_WRITES").await.unwrap();
    stream.purge().sequence(snapshot).await.unwrap();
    assert_eq!(stream.info().await.unwrap().state.first_sequence, snapshot);
    for (kf, _) in &drive[25..] {
        last = insert_one(&first, kf).await;
    }

    // A replica on an empty directory starts from the snapshot and replays
    // the rest, and answers as the first does. Its neighbour graph came
    // with the snapshot (read, not built) and holds every keyframe.
    let second = replica_with(&nats, dirs[1].path(), "second", &settings(0));
    wait_for_position(&second, last, Duration::from_secs(20)).await;
    let (a, b) = (first.stats().await, second.stats().await);
    assert_eq!((b.keyframes, b.log_position), (drive.len() as u64, last));
    assert_eq!(a.maps, b.maps);
    let graph = b.neighbour_graph.expect("the new replica keeps a graph");
    assert!(
        graph.loaded,
        "the graph was built, not read from the snapshot"
    );
    assert_eq!((graph.keyframes, graph.missing), (drive.len() as u64, 0));
    assert_eq!(graph.approximate_from, 1);
    for (kf, _) in drive.iter().step_by(3) {
        let id = scenes::id(kf);
        let (a, b) = (
            ask(&first, "r", id, last).await.unwrap(),
            ask(&second, "r", id, last).await.unwrap(),
        );
        assert!(!a.candidates.is_empty());
        assert_eq!(answer(&a), answer(&b), "keyframe {id}");
    }
    // The map's own graph is not in the snapshot: the new replica builds
    // it in the background, and once it holds every keyframe of the map,
    // loop queries (which walk it) answer as on the first replica.
    let maps_graphs = |stats: &proto::StatsResponse| {
        let graph = stats.neighbour_graph.expect("a graph");
        (
            graph.map_graphs,
            graph.map_graph_keyframes,
            graph.map_graph_waiting,
        )
    };
    let started = Instant::now();
    while maps_graphs(&second.stats().await).2 > 0 {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "the map's graph was not built within 20 s"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let built = maps_graphs(&first.stats().await);
    assert_eq!(built, (1, drive.len() as u64, 0));
    assert_eq!(maps_graphs(&second.stats().await), built);
    for (kf, _) in drive.iter().step_by(3) {
        let id = scenes::id(kf);
        let (a, b) = (
            ask_in(&first, "r", id, last, proto::Scope::SameMap)
                .await
                .unwrap(),
            ask_in(&second, "r", id, last, proto::Scope::SameMap)
                .await
                .unwrap(),
        );
        assert!(!a.candidates.is_empty());
        assert_eq!(answer(&a), answer(&b), "loop query of keyframe {id}");
    }

    // A store written outside cluster mode is never replaced by the
    // snapshot: the replica refuses to start, and the store keeps its own.
    let own = tempfile::tempdir().unwrap();
    {
        let alone = Server::start(own.path());
        scenes::insert_all(
            &mut alone.client().await,
            drive[..3].iter().map(|(kf, _)| kf.clone()),
        )
        .await;
        assert_eq!(alone.stats().await.keyframes, 3);
    }
    let settings = vec![
        "HUMEM_CLUSTER__ENABLED=true".to_string(),
        format!("HUMEM_CLUSTER__NATS_URLS={}", nats.urls_setting()),
        "HUMEM_CLUSTER__STREAM_REPLICAS=1".to_string(),
    ];
    let (ok, stderr) = serve_until_exit(own.path(), &settings);
    assert!(!ok);
    assert!(stderr.contains("written outside cluster mode"), "{stderr}");
    let alone = Server::start(own.path());
    assert_eq!(alone.stats().await.keyframes, 3);
}
