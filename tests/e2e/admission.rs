//! Admission across robots: with one scan slot and a tight wait budget, a
//! burst of queries from many robots is answered or refused at once with
//! RESOURCE_EXHAUSTED and a retry hint; nothing else, and nothing late.

use humem_server::proto;

use crate::harness::Server;

/// A keyframe of `robot` with a synthetic 256-d descriptor.
fn keyframe(robot: &str, id: u64) -> proto::Keyframe {
    let descriptor = (0..256)
        .map(|i| ((id as f32) * 0.37 + i as f32 * 0.11).sin())
        .collect();
    proto::Keyframe {
        robot_id: robot.into(),
        keyframe_id: Some(id),
        frame_id: Some(id),
        map_id: Some(0),
        pose: Some(crate::scenes::pose(id as f64)),
        content: Some(proto::keyframe::Content::Features(proto::Features {
            global_descriptor: descriptor,
            ..Default::default()
        })),
        ..Default::default()
    }
}

fn query(robot: &str) -> proto::QueryRequest {
    proto::QueryRequest {
        robot_id: robot.into(),
        keyframe_id: Some(3),
        scope: proto::Scope::AllMaps as i32,
        ..Default::default()
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn a_burst_beyond_the_scan_budget_is_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with(
        dir.path(),
        &[
            "HUMEM_QUERY__CONCURRENT_SCANS=1",
            "HUMEM_QUERY__MAX_WAIT_MS=1",
        ],
    );
    let mut client = server.client().await;
    // 20 robots x 1000 keyframes: each scan takes some milliseconds.
    for r in 0..20 {
        let robot = format!("robot-{r}");
        for chunk in (0..1000u64).collect::<Vec<_>>().chunks(500) {
            let keyframes = chunk.iter().map(|&id| keyframe(&robot, id)).collect();
            client
                .insert_batch(proto::InsertBatchRequest { keyframes })
                .await
                .expect("insert");
        }
    }
    // One query alone: never refused (nothing ahead), and it times scans.
    let reply = client.query(query("robot-0")).await.unwrap().into_inner();
    assert_eq!(reply.status(), proto::QueryStatus::Answered);

    let mut tasks = Vec::new();
    for r in 0..20 {
        let mut client = server.client().await;
        let request = query(&format!("robot-{r}"));
        tasks.push(tokio::spawn(async move { client.query(request).await }));
    }
    let (mut answered, mut refused) = (0, 0);
    for task in tasks {
        match task.await.unwrap() {
            Ok(reply) => {
                assert_eq!(reply.into_inner().status(), proto::QueryStatus::Answered);
                answered += 1;
            }
            Err(status) => {
                assert_eq!(status.code(), tonic::Code::ResourceExhausted, "{status:?}");
                assert!(status.message().starts_with("server busy: "), "{status:?}");
                assert!(status.message().contains("retry after"), "{status:?}");
                assert!(status.metadata().get("retry-after-ms").is_some());
                refused += 1;
            }
        }
    }
    assert!(
        answered >= 1 && refused >= 1,
        "{answered} answered, {refused} refused"
    );
    let exposition = server.scrape();
    let counted = Server::sample(
        &exposition,
        r#"humem_queries_refused_total{kind="loop_closure"}"#,
    );
    assert_eq!(counted, Some(refused as f64));
}
