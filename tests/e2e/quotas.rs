//! Per-robot quotas through the real binary: a robot over its insert or
//! query rate, or its store size, gets RESOURCE_EXHAUSTED with a
//! `retry-after-ms` hint, other robots are unaffected, and the refusals are
//! counted by kind.

use std::time::Duration;

use humem_server::proto;
use tonic::Code;

use crate::harness::Server;
use crate::scenes::{self, World};

fn retry_after(status: &tonic::Status) -> u64 {
    status
        .metadata()
        .get("retry-after-ms")
        .expect("a retry-after-ms hint")
        .to_str()
        .unwrap()
        .parse()
        .unwrap()
}

#[tokio::test(flavor = "multi_thread")]
async fn a_robot_over_its_quota_is_told_when_to_retry_and_others_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with(
        dir.path(),
        &[
            "HUMEM_QUOTAS__INSERTS_PER_SECOND=20",
            "HUMEM_QUOTAS__QUERIES_PER_SECOND=2",
            "HUMEM_QUOTAS__MAX_KEYFRAMES_PER_ROBOT=30",
        ],
    );
    let mut client = server.client().await;
    let mut world = World::new(40, 5);
    let drive: Vec<_> = scenes::loop_drive(&mut world, "car-1", "s", 0, 40, 0)
        .into_iter()
        .map(|(kf, _)| kf)
        .collect();
    let batch = |range: std::ops::Range<usize>| proto::InsertBatchRequest {
        keyframes: drive[range].to_vec(),
    };

    // A second's worth at once passes; one more at once does not.
    client.insert_batch(batch(0..20)).await.unwrap();
    let status = client.insert_batch(batch(20..21)).await.unwrap_err();
    assert_eq!(status.code(), Code::ResourceExhausted, "{status:?}");
    let wait = retry_after(&status);
    assert!((1..=1000).contains(&wait), "{wait}");
    // Another robot is not held back.
    let mut other = drive[0].clone();
    other.robot_id = "car-2".into();
    client
        .insert(proto::InsertRequest {
            keyframe: Some(other),
        })
        .await
        .unwrap();
    // After the hint, it passes.
    tokio::time::sleep(Duration::from_millis(wait + 20)).await;
    client.insert_batch(batch(20..21)).await.unwrap();

    // Store size: 30 allowed; the 31st is refused, a replacement is not.
    tokio::time::sleep(Duration::from_secs(1)).await;
    client.insert_batch(batch(21..30)).await.unwrap();
    let status = client.insert_batch(batch(30..31)).await.unwrap_err();
    assert_eq!(status.code(), Code::ResourceExhausted);
    assert!(
        status.message().contains("holds 30 keyframes"),
        "{status:?}"
    );
    client.insert_batch(batch(0..1)).await.unwrap();

    // Queries: two a second.
    let query = scenes::query_stored("car-1", "s", 3);
    client.query(query.clone()).await.unwrap();
    client.query(query.clone()).await.unwrap();
    let status = client.query(query.clone()).await.unwrap_err();
    assert_eq!(status.code(), Code::ResourceExhausted);
    assert!(retry_after(&status) >= 1);

    let exposition = server.scrape();
    for kind in ["insert_rate", "store_size", "query_rate"] {
        let series = format!("humem_quota_refused_total{{kind=\"{kind}\"}}");
        assert_eq!(Server::sample(&exposition, &series), Some(1.0), "{series}");
    }
}
