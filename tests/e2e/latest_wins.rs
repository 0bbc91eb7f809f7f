//! Latest wins: a burst of queries from one client leaves the running one
//! and the newest answered and the rest superseded; clients of different
//! robots never supersede each other; deadlines are honoured.

use std::io::Cursor;
use std::time::Duration;

use humem_server::proto;

use crate::harness::Server;

/// A picture with some texture, so that every query runs the models.
fn picture(seed: u8) -> proto::Image {
    let img = image::RgbImage::from_fn(320, 240, |x, y| {
        image::Rgb([
            (x as u8).wrapping_mul(seed),
            (y as u8).wrapping_add(seed),
            ((x ^ y) as u8),
        ])
    });
    let mut jpeg = Vec::new();
    img.write_to(&mut Cursor::new(&mut jpeg), image::ImageFormat::Jpeg)
        .unwrap();
    proto::Image {
        data: jpeg,
        ..Default::default()
    }
}

fn query(robot: &str, frame: u64) -> proto::QueryRequest {
    proto::QueryRequest {
        robot_id: robot.into(),
        session_id: "s".into(),
        frame_id: Some(frame),
        content: Some(proto::query_request::Content::Image(picture(
            frame as u8 + 1,
        ))),
        ..Default::default()
    }
}

/// Sends `n` queries per robot, all at once; returns per robot how many
/// were answered and how many superseded.
async fn burst(server: &Server, robots: &[&str], n: u64) -> Vec<(usize, usize)> {
    let mut tasks = Vec::new();
    for (r, robot) in robots.iter().enumerate() {
        for frame in 0..n {
            let mut client = server.client().await;
            let request = query(robot, frame);
            tasks.push((r, tokio::spawn(async move { client.query(request).await })));
        }
    }
    let mut counts = vec![(0, 0); robots.len()];
    for (r, task) in tasks {
        let reply = task.await.unwrap().expect("query").into_inner();
        match reply.status() {
            proto::QueryStatus::Answered => counts[r].0 += 1,
            proto::QueryStatus::Superseded => {
                assert!(reply.candidates.is_empty());
                counts[r].1 += 1
            }
            other => panic!("unexpected status {other:?}"),
        }
    }
    counts
}

#[tokio::test(flavor = "multi_thread")]
async fn bursts_are_thinned_per_client_and_deadlines_hold() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with_models(dir.path());
    // Something to rank against.
    let mut client = server.client().await;
    client
        .insert(proto::InsertRequest {
            keyframe: Some(proto::Keyframe {
                robot_id: "mapper".into(),
                keyframe_id: Some(0),
                frame_id: Some(0),
                map_id: Some(0),
                pose: Some(crate::scenes::pose(0.0)),
                content: Some(proto::keyframe::Content::Image(picture(7))),
                ..Default::default()
            }),
        })
        .await
        .unwrap();

    // One client: 12 queries at once. The first runs; each newer arrival
    // displaces the one waiting; the newest can never be displaced.
    let counts = burst(&server, &["robot-a"], 12).await;
    let (answered, superseded) = counts[0];
    assert_eq!(answered + superseded, 12);
    assert!(answered >= 2, "{counts:?}");
    assert!(superseded >= 6, "a burst should be thinned: {counts:?}");

    // Two robots at once: each keeps its own first and newest.
    let counts = burst(&server, &["robot-b", "robot-c"], 6).await;
    for (answered, superseded) in &counts {
        assert_eq!(answered + superseded, 6);
        assert!(
            *answered >= 2,
            "robots must not supersede each other: {counts:?}"
        );
    }

    // The metrics saw it, and every queue drained.
    let exposition = server.scrape();
    let sample = |series: &str| Server::sample(&exposition, series).unwrap_or(0.0);
    assert!(sample(r#"humem_queries_superseded_total{kind="loop_closure"}"#) >= 6.0);
    assert!(sample(r#"humem_batch_size_count{model="descriptor"}"#) >= 1.0);
    for queue in [
        "descriptor",
        "ocr-det",
        "ocr-rec",
        "queries",
        "store_writer",
    ] {
        let series = format!("humem_queue_depth{{queue=\"{queue}\"}}");
        assert_eq!(sample(&series), 0.0, "{series}");
    }

    // A deadline shorter than the models take ends the query (tonic's
    // server reports it as CANCELLED "Timeout expired"), and the slot is
    // free again afterwards.
    let mut request = tonic::Request::new(query("robot-d", 0));
    request.set_timeout(Duration::from_millis(1));
    let status = client.query(request).await.unwrap_err();
    assert!(
        matches!(
            status.code(),
            tonic::Code::Cancelled | tonic::Code::DeadlineExceeded
        ),
        "{status:?}"
    );
    let reply = client
        .query(query("robot-d", 1))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(reply.status(), proto::QueryStatus::Answered);
}

#[tokio::test(flavor = "multi_thread")]
async fn sigterm_lets_in_flight_queries_finish_and_exits_zero() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with_models(dir.path());
    let mut tasks = Vec::new();
    for (i, robot) in ["a", "b", "c", "d"].iter().enumerate() {
        let mut client = server.client().await;
        let request = query(robot, i as u64);
        tasks.push(tokio::spawn(async move { client.query(request).await }));
    }
    tokio::time::sleep(Duration::from_millis(20)).await;
    let status = tokio::task::spawn_blocking(move || server.terminate())
        .await
        .unwrap();
    for task in tasks {
        let reply = task
            .await
            .unwrap()
            .expect("in-flight query finished")
            .into_inner();
        assert_eq!(reply.status(), proto::QueryStatus::Answered);
    }
    assert!(status.success(), "exit status {status}");
}
