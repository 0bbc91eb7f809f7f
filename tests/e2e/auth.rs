//! Credentials and access rules through the real binary over real TLS:
//! tokens made and revoked with `humem token`, a client certificate as an
//! identity, writes only for the caller's own robot, reads narrowed to what
//! the access rules share, and the refusal to serve a network address
//! without TLS and credentials.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use humem_server::client::{ClientCredentials, Connection};
use humem_server::proto;
use humem_server::proto::place_recognition_client::PlaceRecognitionClient;
use tonic::Code;

use crate::harness::Server;
use crate::pki::Authority;
use crate::scenes::{self, World};
use crate::tls::{https, tls_env, trusting};

/// `humem token ARGS... --file FILE`; its stdout.
fn token_command(file: &Path, args: &[&str]) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_humem"))
        .arg("token")
        .args(args)
        .arg("--file")
        .arg(file)
        .env_remove("HUMEM_CONFIG")
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "humem token {args:?}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).unwrap()
}

/// A server with TLS, a token file and one fleet group.
struct Fleet {
    _dir: tempfile::TempDir,
    server: Server,
    ca: PathBuf,
    tokens: PathBuf,
    authority: Authority,
    dir: PathBuf,
}

impl Fleet {
    fn start(client_certificates: bool) -> Fleet {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().to_path_buf();
        let authority = Authority::new("Fleet CA");
        let ca = authority.write_ca(&path, "ca");
        let (cert, key) = authority.issue(&path, "server", &["localhost", "127.0.0.1"]);
        let tokens = path.join("tokens.json");
        let config = path.join("humem.toml");
        let mut text = format!(
            "[auth]\ntokens_file = {:?}\ncertificate_admins = [\"ops-console\"]\n[auth.groups]\nnorth = [\"car-1\", \"car-2\"]\n",
            tokens.display().to_string()
        );
        if client_certificates {
            text.push_str(&format!(
                "[server.tls]\nclient_ca = {:?}\nclient_auth = \"optional\"\n",
                ca.display().to_string()
            ));
        }
        std::fs::write(&config, text).unwrap();
        let mut args = tls_env(&cert, &key);
        args.push(format!("HUMEM_CONFIG={}", config.display()));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let server = Server::start_with(&path.join("data"), &args);
        Fleet {
            _dir: dir,
            server,
            ca,
            tokens,
            authority,
            dir: path,
        }
    }

    /// A new token, once the running server takes it (it reads the token
    /// file again within a second of a change).
    async fn token(&self, robot: &str, admin: bool) -> String {
        let mut args = vec!["add", "--robot", robot];
        if admin {
            args.extend(["--role", "admin"]);
        }
        let token = token_command(&self.tokens, &args).trim().to_string();
        let added = Instant::now();
        let mut client = self.client(Some(&token)).await;
        while client.stats(proto::StatsRequest {}).await.is_err() {
            assert!(
                added.elapsed() < Duration::from_secs(1),
                "a new token was not taken within 1 s"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        token
    }

    fn credentials(&self, token: Option<&str>) -> ClientCredentials {
        ClientCredentials {
            token: token.map(str::to_string),
            ..trusting(&self.ca)
        }
    }

    async fn client(&self, token: Option<&str>) -> PlaceRecognitionClient<Connection> {
        humem_server::client::connect(&https(&self.server), &self.credentials(token))
            .await
            .unwrap()
    }

    /// Stores `robot`'s drive through places 0..n (session "s", map 0),
    /// in one batch with its token.
    async fn store_drive(&self, world: &mut World, robot: &str, token: &str, n: usize) {
        let keyframes: Vec<_> = scenes::loop_drive(world, robot, "s", 0, n, 0)
            .into_iter()
            .map(|(kf, _)| kf)
            .collect();
        self.client(Some(token))
            .await
            .insert_batch(proto::InsertBatchRequest { keyframes })
            .await
            .unwrap();
    }

    fn denied(&self, reason: &str) -> f64 {
        let exposition = self.server.scrape();
        exposition
            .lines()
            .filter(|l| l.starts_with("humem_auth_denied_total{") && l.contains(reason))
            .map(|l| l.rsplit_once(' ').unwrap().1.parse::<f64>().unwrap())
            .sum()
    }
}

/// Keyframes of `robot` at places 0..n, all of the same world (so every
/// robot's keyframe of a place looks alike).
fn drive(world: &mut World, robot: &str, n: usize) -> Vec<proto::Keyframe> {
    scenes::loop_drive(world, robot, "s", 0, n, 0)
        .into_iter()
        .map(|(kf, _)| kf)
        .collect()
}

async fn keyframes(client: &mut PlaceRecognitionClient<Connection>) -> u64 {
    client
        .stats(proto::StatsRequest {})
        .await
        .unwrap()
        .into_inner()
        .keyframes
}

/// Every RPC, for a request of `robot`.
async fn every_rpc(
    client: &mut PlaceRecognitionClient<Connection>,
    robot: &str,
    kf: &proto::Keyframe,
) -> Vec<(&'static str, tonic::Status)> {
    let mut kf = kf.clone();
    kf.robot_id = robot.into();
    let session = || (robot.to_string(), "s".to_string());
    let mut out = Vec::new();
    let mut record = |rpc, result: Result<(), tonic::Status>| {
        out.push((rpc, result.err().unwrap_or_else(|| tonic::Status::ok(""))));
    };
    let r = client
        .insert(proto::InsertRequest {
            keyframe: Some(kf.clone()),
        })
        .await;
    record("Insert", r.map(|_| ()));
    let r = client
        .insert_batch(proto::InsertBatchRequest {
            keyframes: vec![kf.clone()],
        })
        .await;
    record("InsertBatch", r.map(|_| ()));
    let r = client
        .query(proto::QueryRequest {
            robot_id: robot.into(),
            session_id: "s".into(),
            frame_id: Some(1),
            map_id: Some(0),
            content: Some(proto::query_request::Content::Features(
                scenes::features_of(&kf),
            )),
            ..Default::default()
        })
        .await;
    record("Query", r.map(|_| ()));
    let (robot_id, session_id) = session();
    let r = client
        .erase(proto::EraseRequest {
            robot_id,
            session_id,
            keyframe_ids: vec![0],
        })
        .await;
    record("Erase", r.map(|_| ()));
    let (robot_id, session_id) = session();
    let r = client
        .reset_map(proto::ResetMapRequest {
            robot_id,
            session_id,
            map_id: Some(0),
        })
        .await;
    record("ResetMap", r.map(|_| ()));
    let (robot_id, session_id) = session();
    let r = client
        .update_poses(proto::UpdatePosesRequest {
            robot_id,
            session_id,
            updates: vec![proto::PoseUpdate {
                keyframe_id: Some(0),
                pose: Some(scenes::pose(1.0)),
                map_id: None,
            }],
        })
        .await;
    record("UpdatePoses", r.map(|_| ()));
    let (robot_id, session_id) = session();
    let r = client
        .reset_session(proto::ResetSessionRequest {
            robot_id,
            session_id,
        })
        .await;
    record("ResetSession", r.map(|_| ()));
    out
}

#[tokio::test(flavor = "multi_thread")]
async fn every_rpc_needs_a_valid_credential_and_acts_only_for_its_robot() {
    let fleet = Fleet::start(false);
    let car1 = fleet.token("car-1", false).await;
    let ops = fleet.token("ops", true).await;
    let mut world = World::new(10, 3);
    let own = drive(&mut world, "car-1", 10);
    let other = drive(&mut world, "car-2", 10);
    let mut admin = fleet.client(Some(&ops)).await;
    admin
        .insert_batch(proto::InsertBatchRequest {
            keyframes: other.clone(),
        })
        .await
        .unwrap();
    // Counted from here: waiting for the new tokens above was refused too.
    let unauthenticated_before = fleet.denied("unauthenticated");
    let mut denials = 0;

    // No credential, a revoked-looking token, a malformed one: every RPC
    // (Stats too) is UNAUTHENTICATED, and nothing changes.
    for token in [
        None,
        Some("hm1.00000000.".to_string() + &"0".repeat(64)),
        Some("secret".into()),
    ] {
        let mut client = fleet.client(token.as_deref()).await;
        for (rpc, status) in every_rpc(&mut client, "car-1", &own[0]).await {
            assert_eq!(
                status.code(),
                Code::Unauthenticated,
                "{rpc} with {token:?}: {status:?}"
            );
            denials += 1;
        }
        let status = client.stats(proto::StatsRequest {}).await.unwrap_err();
        assert_eq!(status.code(), Code::Unauthenticated);
        denials += 1;
    }
    assert_eq!(
        fleet.denied("unauthenticated") - unauthenticated_before,
        denials as f64
    );

    // car-1's token for car-2's robot id: PERMISSION_DENIED on every write,
    // maintenance call and query, and car-2's keyframes stay.
    let mut client = fleet.client(Some(&car1)).await;
    let mut refused = 0;
    for (rpc, status) in every_rpc(&mut client, "car-2", &own[0]).await {
        assert_eq!(status.code(), Code::PermissionDenied, "{rpc}: {status:?}");
        assert!(status.message().contains("robot_id"), "{rpc}: {status:?}");
        refused += 1;
    }
    // A batch with one keyframe of another robot is refused whole.
    let mut mixed = own[..3].to_vec();
    mixed.push(other[5].clone());
    let status = client
        .insert_batch(proto::InsertBatchRequest { keyframes: mixed })
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::PermissionDenied);
    assert!(
        status.message().contains("keyframes[3].robot_id"),
        "{status:?}"
    );
    refused += 1;
    assert_eq!(fleet.denied("permission_denied"), refused as f64);
    assert_eq!(keyframes(&mut admin).await, 10, "nothing changed");

    // For its own robot, every RPC is allowed.
    for (rpc, status) in every_rpc(&mut client, "car-1", &own[0]).await {
        assert_eq!(status.code(), Code::Ok, "{rpc}: {status:?}");
    }
    // A verdict is a write of the query's robot, and may name only a
    // candidate the caller may read (car-2 shares car-1's group; truck-9
    // does not).
    client
        .insert_batch(proto::InsertBatchRequest {
            keyframes: own[..2].to_vec(),
        })
        .await
        .unwrap();
    let verdict = |robot: &str, candidate_robot: &str| proto::ReportVerificationRequest {
        robot_id: robot.into(),
        session_id: "s".into(),
        keyframe_id: Some(scenes::id(&own[1])),
        candidate: Some(proto::KeyframeRef {
            robot_id: candidate_robot.into(),
            session_id: "s".into(),
            keyframe_id: Some(scenes::id(&own[0])),
        }),
        kind: proto::VerificationKind::Loop as i32,
        outcome: proto::VerificationOutcome::Rejected as i32,
        ..Default::default()
    };
    client
        .report_verification(verdict("car-1", "car-1"))
        .await
        .unwrap();
    let status = client
        .report_verification(verdict("car-2", "car-1"))
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::PermissionDenied, "{status:?}");
    assert!(status.message().contains("robot_id"), "{status:?}");
    let status = client
        .report_verification(verdict("car-1", "truck-9"))
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::PermissionDenied, "{status:?}");
    assert!(
        status.message().contains("candidate.robot_id"),
        "{status:?}"
    );
    let stats = admin.stats(proto::StatsRequest {}).await.unwrap();
    assert_eq!(stats.into_inner().verdicts, 1);

    // The admin acts for any robot.
    let erased = admin
        .reset_session(proto::ResetSessionRequest {
            robot_id: "car-2".into(),
            session_id: "s".into(),
        })
        .await
        .unwrap()
        .into_inner()
        .erased;
    assert_eq!(erased, 10);

    // Health needs no credential.
    let channel = humem_server::client::channel(&https(&fleet.server), &trusting(&fleet.ca))
        .await
        .unwrap();
    let health = tonic_health::pb::health_client::HealthClient::new(channel)
        .check(tonic_health::pb::HealthCheckRequest {
            service: String::new(),
        })
        .await
        .unwrap();
    assert_eq!(health.into_inner().status, 1);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_revoked_token_is_refused_within_a_second_and_a_new_one_works_without_restart() {
    let fleet = Fleet::start(false);
    let token = fleet.token("car-1", false).await;
    let mut client = fleet.client(Some(&token)).await;
    assert_eq!(keyframes(&mut client).await, 0);
    let listed = token_command(&fleet.tokens, &["list"]);
    let id = token.split('.').nth(1).unwrap();
    assert!(listed.contains(id) && listed.contains("car-1"), "{listed}");
    assert!(
        !listed.contains(token.rsplit('.').next().unwrap()),
        "the secret is never listed"
    );

    token_command(&fleet.tokens, &["revoke", id]);
    let revoked = Instant::now();
    loop {
        match client.stats(proto::StatsRequest {}).await {
            Err(status) => {
                assert_eq!(status.code(), Code::Unauthenticated);
                break;
            }
            Ok(_) => {
                assert!(
                    revoked.elapsed() < Duration::from_secs(1),
                    "the revoked token was still accepted after 1 s"
                );
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }
    }
    eprintln!("revoked token refused after {:?}", revoked.elapsed());

    // A token added while the server runs works within a second too
    // (`Fleet::token` waits for it).
    let fresh = fleet.token("car-1", false).await;
    assert_eq!(keyframes(&mut fleet.client(Some(&fresh)).await).await, 0);
}

#[tokio::test(flavor = "multi_thread")]
async fn reads_are_narrowed_to_the_maps_the_rules_share_for_every_scope() {
    let fleet = Fleet::start(false);
    let car1 = fleet.token("car-1", false).await;
    let car2 = fleet.token("car-2", false).await;
    let van = fleet.token("van-9", false).await;
    let ops = fleet.token("ops", true).await;
    let mut world = World::new(20, 11);
    // Three robots drive the same places; car-1 and car-2 share group
    // "north", van-9 is in no group.
    for (robot, token) in [("car-1", &car1), ("car-2", &car2), ("van-9", &van)] {
        fleet.store_drive(&mut world, robot, token, 20).await;
    }
    let query = |robot: &str, scope: proto::Scope, robots: &[&str]| proto::QueryRequest {
        robot_id: robot.into(),
        session_id: "s".into(),
        keyframe_id: Some(7),
        scope: scope as i32,
        robot_ids: robots.iter().map(|r| r.to_string()).collect(),
        min_frame_gap: Some(0),
        top_n: Some(50),
        threshold: Some(0.0),
        ..Default::default()
    };
    let scopes = [
        (proto::Scope::AllMaps, vec![]),
        (proto::Scope::Unspecified, vec![]),
        (proto::Scope::OtherMaps, vec![]),
        (proto::Scope::SameMap, vec![]),
        (proto::Scope::Listed, vec!["van-9", "car-2"]),
        (proto::Scope::Listed, vec!["van-9"]),
    ];
    let mut cases = 0;
    for (asker, token, readable) in [
        ("car-1", &car1, vec!["car-1", "car-2"]),
        ("car-2", &car2, vec!["car-1", "car-2"]),
        ("van-9", &van, vec!["van-9"]),
    ] {
        let mut client = fleet.client(Some(token)).await;
        for (scope, listed) in &scopes {
            let reply = client
                .query(query(asker, *scope, listed))
                .await
                .unwrap()
                .into_inner();
            for c in &reply.candidates {
                assert!(
                    readable.contains(&c.robot_id.as_str()),
                    "{asker} {scope:?} {listed:?}: got {}'s keyframe",
                    c.robot_id
                );
            }
            // Nothing unreadable is even counted as eligible: at most 20
            // keyframes per readable robot, one fewer of the asker's own.
            assert!(reply.eligible_keyframes <= 20 * readable.len() as u64);
            cases += 1;
        }
        // ALL_MAPS reaches every readable robot's keyframes.
        let reply = client
            .query(query(asker, proto::Scope::AllMaps, &[]))
            .await
            .unwrap()
            .into_inner();
        assert_eq!(reply.eligible_keyframes, 20 * readable.len() as u64 - 1);
        // Stats lists only readable robots' maps.
        let stats = client
            .stats(proto::StatsRequest {})
            .await
            .unwrap()
            .into_inner();
        let mut robots: Vec<_> = stats.maps.iter().map(|m| m.robot_id.as_str()).collect();
        robots.sort();
        assert_eq!(robots, readable, "{asker}");
        // Nor is anything counted of the others: 20 keyframes a readable
        // robot, and not the size of the whole store.
        assert_eq!(stats.keyframes, 20 * readable.len() as u64, "{asker}");
        assert_eq!(stats.disk_bytes, 0, "{asker}");
    }
    assert_eq!(cases, 18);
    // The admin, acting for car-1, reads every robot.
    let reply = fleet
        .client(Some(&ops))
        .await
        .query(query("car-1", proto::Scope::AllMaps, &[]))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(reply.eligible_keyframes, 59);
    let robots: std::collections::BTreeSet<_> = reply
        .candidates
        .iter()
        .map(|c| c.robot_id.clone())
        .collect();
    assert_eq!(robots.len(), 3, "{robots:?}");
}

/// The robots whose maps `client`'s Stats lists.
async fn robots_listed(client: &mut PlaceRecognitionClient<Connection>) -> Vec<String> {
    let stats = client
        .stats(proto::StatsRequest {})
        .await
        .unwrap()
        .into_inner();
    let robots: BTreeSet<String> = stats.maps.into_iter().map(|m| m.robot_id).collect();
    robots.into_iter().collect()
}

#[tokio::test(flavor = "multi_thread")]
async fn group_changes_take_effect_without_a_restart_and_a_broken_file_changes_nothing() {
    let fleet = Fleet::start(false);
    let car1 = fleet.token("car-1", false).await;
    let car2 = fleet.token("car-2", false).await;
    let mut world = World::new(5, 3);
    for (robot, token) in [("car-1", &car1), ("car-2", &car2)] {
        fleet.store_drive(&mut world, robot, token, 5).await;
    }
    let mut client = fleet.client(Some(&car1)).await;
    assert_eq!(robots_listed(&mut client).await, ["car-1", "car-2"]);

    let config = fleet.dir.join("humem.toml");
    let text = std::fs::read_to_string(&config).unwrap();
    let watcher = client.clone();
    let wait_for = |expected: &'static [&'static str]| {
        let mut client = watcher.clone();
        async move {
            let changed = Instant::now();
            loop {
                let listed = robots_listed(&mut client).await;
                if listed == expected {
                    return changed.elapsed();
                }
                assert!(
                    changed.elapsed() < Duration::from_secs(2),
                    "still {listed:?}, not {expected:?}, 2 s after the change"
                );
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }
    };
    // car-2 leaves the group: car-1 stops reading its maps, no restart.
    std::fs::write(
        &config,
        text.replace("north = [\"car-1\", \"car-2\"]", "north = [\"car-1\"]"),
    )
    .unwrap();
    wait_for(&["car-1"]).await;
    // A broken file (half written) changes nothing.
    std::fs::write(&config, "[auth\ngroups = ").unwrap();
    tokio::time::sleep(Duration::from_millis(800)).await;
    assert_eq!(robots_listed(&mut client).await, ["car-1"]);
    // Nor does a valid file whose settings are refused: a group's robots
    // must be listed.
    std::fs::write(
        &config,
        text.replace("north = [\"car-1\", \"car-2\"]", "north = 3"),
    )
    .unwrap();
    tokio::time::sleep(Duration::from_millis(800)).await;
    assert_eq!(robots_listed(&mut client).await, ["car-1"]);
    // car-2 back in the group: shared again.
    std::fs::write(&config, &text).unwrap();
    wait_for(&["car-1", "car-2"]).await;
}

#[tokio::test(flavor = "multi_thread")]
async fn a_client_certificate_speaks_for_the_robot_it_names() {
    let fleet = Fleet::start(true);
    let (cert, key) = fleet.authority.issue(&fleet.dir, "car-1", &["car-1"]);
    let (admin_cert, admin_key) =
        fleet
            .authority
            .issue(&fleet.dir, "ops-console", &["ops-console"]);
    let with_cert = |cert: &Path, key: &Path| ClientCredentials {
        tls_cert: Some(cert.to_path_buf()),
        tls_key: Some(key.to_path_buf()),
        ..trusting(&fleet.ca)
    };
    let url = https(&fleet.server);
    let mut car1 = humem_server::client::connect(&url, &with_cert(&cert, &key))
        .await
        .unwrap();
    let mut world = World::new(5, 2);
    let own = drive(&mut world, "car-1", 5);
    car1.insert_batch(proto::InsertBatchRequest {
        keyframes: own.clone(),
    })
    .await
    .unwrap();
    let mut as_car2 = own[0].clone();
    as_car2.robot_id = "car-2".into();
    let status = car1
        .insert(proto::InsertRequest {
            keyframe: Some(as_car2.clone()),
        })
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::PermissionDenied);
    // A certificate named as an admin acts for anyone.
    let mut admin = humem_server::client::connect(&url, &with_cert(&admin_cert, &admin_key))
        .await
        .unwrap();
    admin
        .insert(proto::InsertRequest {
            keyframe: Some(as_car2),
        })
        .await
        .unwrap();
    assert_eq!(keyframes(&mut admin).await, 6);
    // Neither certificate nor token (client certificates are optional
    // here): UNAUTHENTICATED.
    let status = fleet
        .client(None)
        .await
        .stats(proto::StatsRequest {})
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::Unauthenticated);
}

#[test]
fn a_network_address_without_tls_and_credentials_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let serve = |env: &[(&str, String)]| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_humem"));
        command
            .args(["serve", "--listen", "0.0.0.0:0", "--data-dir"])
            .arg(dir.path().join("data"))
            .env_remove("HUMEM_CONFIG")
            .env("HUMEM_PERCEPTION__ENABLED", "false")
            .env("HUMEM_METRICS__ENABLED", "false");
        for (key, value) in env {
            command.env(key, value);
        }
        command
    };
    let authority = Authority::new("CA");
    let (cert, key) = authority.issue(dir.path(), "server", &["localhost"]);
    let tls = [
        ("HUMEM_SERVER__TLS__CERT", cert.display().to_string()),
        ("HUMEM_SERVER__TLS__KEY", key.display().to_string()),
    ];
    let tokens = (
        "HUMEM_AUTH__TOKENS_FILE",
        dir.path().join("tokens.json").display().to_string(),
    );
    for (env, missing) in [
        (vec![], "without TLS and credentials"),
        (tls.to_vec(), "without credentials"),
        (vec![tokens.clone()], "without TLS"),
    ] {
        let output = serve(&env).output().unwrap();
        assert!(!output.status.success(), "{env:?}");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(stderr.contains(missing), "{env:?}: {stderr}");
        assert!(stderr.contains("server.allow_insecure_network"), "{stderr}");
    }
    // With both, or with the setting that allows it, it serves.
    let mut both = tls.to_vec();
    both.push(tokens);
    for env in [
        both,
        vec![("HUMEM_SERVER__ALLOW_INSECURE_NETWORK", "true".to_string())],
    ] {
        let mut child = serve(&env)
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let mut line = String::new();
        std::io::BufRead::read_line(
            &mut std::io::BufReader::new(child.stdout.take().unwrap()),
            &mut line,
        )
        .unwrap();
        child.kill().unwrap();
        child.wait().unwrap();
        assert!(
            line.starts_with("humem listening on 0.0.0.0:"),
            "{env:?}: {line:?}"
        );
    }
}
