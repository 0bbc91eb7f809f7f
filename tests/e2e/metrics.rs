//! The Prometheus endpoint of the real binary moves with traffic, and the
//! ingest queue pushes back instead of growing under a flood.

use humem_server::proto;

use crate::harness::{output_of, Server};
use crate::scenes::{self, World};

#[tokio::test(flavor = "multi_thread")]
async fn metrics_follow_traffic() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let before = server.scrape();
    // Unlabelled series exist from the start.
    assert_eq!(
        Server::sample(&before, "humem_keyframes_inserted_total"),
        Some(0.0)
    );
    assert!(Server::sample(&before, "humem_store_disk_bytes").is_some());

    let mut client = server.client().await;
    let mut world = World::new(60, 9);
    let drive = scenes::loop_drive(&mut world, "robot-m", "s", 4, 60, 10);
    scenes::insert_all(&mut client, drive.iter().map(|(kf, _)| kf.clone())).await;
    for (kf, _) in &drive[60..] {
        client
            .query(scenes::query_stored("robot-m", "s", scenes::id(kf)))
            .await
            .unwrap();
    }
    client
        .erase(proto::EraseRequest {
            robot_id: String::new(),
            session_id: String::new(),
            keyframe_ids: vec![1],
        })
        .await
        .unwrap_err();

    let after = server.scrape();
    let sample = |series: &str| {
        Server::sample(&after, series).unwrap_or_else(|| panic!("no {series} in\n{after}"))
    };
    assert_eq!(sample("humem_keyframes_inserted_total"), 70.0);
    assert_eq!(
        sample(r#"humem_rpc_requests_total{code="OK",rpc="InsertBatch"}"#),
        1.0
    );
    assert_eq!(
        sample(r#"humem_rpc_requests_total{code="OK",rpc="Query"}"#),
        10.0
    );
    assert_eq!(
        sample(r#"humem_rpc_requests_total{code="INVALID_ARGUMENT",rpc="Erase"}"#),
        1.0
    );
    assert_eq!(
        sample(r#"humem_rpc_duration_seconds_count{rpc="Query"}"#),
        10.0
    );
    assert_eq!(
        sample(r#"humem_stage_duration_seconds_count{stage="scal"}"#),
        10.0
    );
    assert_eq!(
        sample(r#"humem_query_candidates_count{kind="loop_closure"}"#),
        10.0
    );
    assert!(sample(r#"humem_candidate_score_count{kind="loop_closure"}"#) >= 10.0);
    assert_eq!(
        sample(r#"humem_keyframes{map="4",robot="robot-m",session="s"}"#),
        70.0
    );
    assert!(sample("humem_store_disk_bytes") > 0.0);
    assert_eq!(sample(r#"humem_queue_depth{queue="store_writer"}"#), 0.0);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_flood_of_inserts_is_pushed_back_not_queued_without_bound() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with(dir.path(), &["HUMEM_STORE__WRITE_QUEUE=2"]);
    let mut world = World::new(64, 10);
    let drive = scenes::loop_drive(&mut world, "flood", "s", 0, 64, 0);
    let mut tasks = Vec::new();
    for chunk in drive.chunks(2) {
        for _ in 0..4 {
            let mut client = server.client().await;
            let keyframes: Vec<_> = chunk.iter().map(|(kf, _)| kf.clone()).collect();
            tasks.push(tokio::spawn(async move {
                client
                    .insert_batch(proto::InsertBatchRequest { keyframes })
                    .await
            }));
        }
    }
    let (mut ok, mut pushed_back) = (0, 0);
    for task in tasks {
        match task.await.unwrap() {
            Ok(_) => ok += 1,
            Err(status) => {
                assert_eq!(status.code(), tonic::Code::ResourceExhausted, "{status:?}");
                assert!(status.metadata().get("retry-after-ms").is_some());
                pushed_back += 1;
            }
        }
    }
    assert_eq!(ok + pushed_back, 128);
    assert!(
        ok > 0 && pushed_back > 0,
        "ok {ok}, pushed back {pushed_back}"
    );
    let exposition = server.scrape();
    let depth = Server::sample(&exposition, r#"humem_queue_depth{queue="store_writer"}"#).unwrap();
    assert!(depth <= 2.0);
    // Every accepted insert is stored; the store holds only whole batches.
    let stats = server
        .client()
        .await
        .stats(proto::StatsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert!(stats.keyframes > 0 && stats.keyframes % 2 == 0 && stats.keyframes <= 64);
}

#[tokio::test(flavor = "multi_thread")]
async fn the_load_generator_reports_what_it_achieved() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let text = output_of(
        std::process::Command::new(env!("CARGO_BIN_EXE_humem")).args([
            "load",
            "--server",
            &server.url,
            "--robots",
            "3",
            "--rate",
            "20",
            "--duration",
            "2",
        ]),
    );
    let row = |call: &str| load_row(&text, call);
    // sent, ok, superseded, errors, ok/s, p50, p95, p99, max
    let insert = row("insert");
    assert!(insert[0] >= 100.0, "{text}");
    assert_eq!(insert[3], 0.0, "{text}");
    let query = row("query");
    assert_eq!(query[0], insert[1], "one query per stored keyframe: {text}");
    assert_eq!(query[1] + query[2], query[0], "{text}");
    let exposition = server.scrape();
    assert_eq!(
        Server::sample(&exposition, "humem_keyframes_inserted_total"),
        Some(insert[1])
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn the_load_generator_asks_loop_and_merge_queries_and_checks_the_graph_against_exact() {
    let dir = tempfile::tempdir().unwrap();
    // Every merge query takes its candidates from the neighbour graph.
    let server = Server::start_with(dir.path(), &["HUMEM_VPR__APPROXIMATE_FROM=1"]);
    let text = output_of(
        std::process::Command::new(env!("CARGO_BIN_EXE_humem")).args([
            "load",
            "--server",
            &server.url,
            "--robots",
            "4",
            "--rate",
            "20",
            "--duration",
            "3",
            "--scopes",
            "same-map,other-maps",
            "--exact-every",
            "3",
        ]),
    );
    let row = |call: &str| load_row(&text, call);
    let insert = row("insert");
    for scope in ["query/same-map", "query/other-maps"] {
        let query = row(scope);
        assert_eq!(
            query[0], insert[1],
            "one {scope} per stored keyframe: {text}"
        );
        assert_eq!(query[3], 0.0, "{text}");
    }
    // "exact check: S of C sampled queries (P %) …"
    let check = text
        .lines()
        .find(|l| l.starts_with("exact check:"))
        .unwrap_or_else(|| panic!("no exact check in\n{text}"));
    let numbers: Vec<f64> = check
        .split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .filter_map(|w| w.parse().ok())
        .collect();
    let (same, compared) = (numbers[0], numbers[1]);
    assert!(compared >= 20.0, "{text}");
    assert!(same >= 0.85 * compared, "{text}");
}

/// The figures of `humem load`'s row for `call` (sent, ok, superseded,
/// errors, ok/s, p50, p95, p99, max).
fn load_row(text: &str, call: &str) -> Vec<f64> {
    text.lines()
        .find(|l| l.starts_with(call))
        .unwrap_or_else(|| panic!("no {call} row in\n{text}"))
        .split_whitespace()
        .skip(1)
        .map(|v| v.parse().unwrap())
        .collect()
}
