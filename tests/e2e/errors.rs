//! Bad requests get INVALID_ARGUMENT naming the field and change nothing;
//! the standard health and reflection services answer.

use humem_server::proto;
use tonic::Code;

use crate::harness::Server;
use crate::scenes::{self, World};

fn features(kf: &mut proto::Keyframe) -> &mut proto::Features {
    match kf.content.as_mut() {
        Some(proto::keyframe::Content::Features(f)) => f,
        _ => panic!("keyframe without features"),
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn bad_requests_are_refused_with_the_field_named_and_change_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut client = server.client().await;
    let mut world = World::new(5, 7);
    let good = scenes::loop_drive(&mut world, "r", "s", 0, 5, 0);
    scenes::insert_all(&mut client, good.iter().map(|(kf, _)| kf.clone())).await;
    let base = || good[0].0.clone();

    type Edit = Box<dyn Fn(&mut proto::Keyframe)>;
    let cases: Vec<(&str, Edit)> =
        vec![
        ("keyframe.robot_id: required", Box::new(|k| k.robot_id.clear())),
        ("keyframe.keyframe_id: required", Box::new(|k| k.keyframe_id = None)),
        ("keyframe.frame_id: required", Box::new(|k| k.frame_id = None)),
        ("keyframe.map_id: required", Box::new(|k| k.map_id = None)),
        ("keyframe.pose: required", Box::new(|k| k.pose = None)),
        ("keyframe.features: required (or an image)", Box::new(|k| k.content = None)),
        ("keyframe.timestamp: not a finite number", Box::new(|k| k.timestamp = f64::INFINITY)),
        (
            "keyframe.pose.rotation: quaternion has zero length",
            Box::new(|k| k.pose.as_mut().unwrap().rotation = Some(proto::Quaternion::default())),
        ),
        (
            "keyframe.features.global_descriptor[3]: not a finite number",
            Box::new(|k| features(k).global_descriptor[3] = f32::NAN),
        ),
        (
            "keyframe.features.global_descriptor: has 65 values but this store holds 64-value descriptors",
            Box::new(|k| features(k).global_descriptor.push(0.5)),
        ),
        (
            "keyframe.features.global_descriptor: 9000 values, at most 8192",
            Box::new(|k| features(k).global_descriptor = vec![0.1; 9000]),
        ),
        (
            "keyframe.features.global_descriptor: all values are zero",
            Box::new(|k| features(k).global_descriptor = vec![0.0; 64]),
        ),
        (
            "keyframe.features.appearance: 100 bytes, expected none or 3072 (64x48)",
            Box::new(|k| features(k).appearance = vec![1; 100]),
        ),
        (
            "keyframe.features.objects[0].confidence: 1.5 is outside [0, 1]",
            Box::new(|k| features(k).objects[0].confidence = 1.5),
        ),
        (
            "keyframe.features.objects[0].x: -0.1 is outside [0, 1]",
            Box::new(|k| features(k).objects[0].x = -0.1),
        ),
        (
            "keyframe.features.objects[0].texts[0].confidence: not a finite number",
            Box::new(|k| features(k).objects[0].texts[0].confidence = f32::NAN),
        ),
        (
            "keyframe.features.objects[0].class_name: required",
            Box::new(|k| features(k).objects[0].class_name.clear()),
        ),
        (
            "keyframe.features.objects: 300 objects, at most 256",
            Box::new(|k| {
                let o = features(k).objects[0].clone();
                features(k).objects = vec![o; 300];
            }),
        ),
        (
            "keyframe.features.scene: probabilities sum to 1.2000, more than 1",
            Box::new(|k| {
                features(k).scene = vec![
                    proto::SceneClass { class_id: 1, probability: 0.6 },
                    proto::SceneClass { class_id: 2, probability: 0.6 },
                ]
            }),
        ),
    ];
    for (expected, edit) in &cases {
        // Each bad keyframe gets a fresh id, so that a wrongly accepted one
        // would show up as a new keyframe.
        let mut kf = base();
        kf.keyframe_id = Some(777);
        edit(&mut kf);
        let status = client
            .insert(proto::InsertRequest {
                keyframe: Some(kf.clone()),
            })
            .await
            .expect_err(expected);
        assert_eq!(
            status.code(),
            Code::InvalidArgument,
            "{expected}: {status:?}"
        );
        assert_eq!(status.message(), *expected);
        // In a batch, the whole batch is refused and the index is named.
        let mut ok = base();
        ok.keyframe_id = Some(778);
        let status = client
            .insert_batch(proto::InsertBatchRequest {
                keyframes: vec![ok, kf],
            })
            .await
            .expect_err(expected);
        assert_eq!(status.code(), Code::InvalidArgument);
        let in_batch = expected.replacen("keyframe.", "keyframes[1].", 1);
        assert_eq!(status.message(), in_batch);
    }

    let status = client
        .insert(proto::InsertRequest { keyframe: None })
        .await
        .unwrap_err();
    assert_eq!(
        (status.code(), status.message()),
        (Code::InvalidArgument, "keyframe: required")
    );

    // Queries.
    let query = || scenes::query_stored("r", "s", 2);
    type QueryEdit = Box<dyn Fn(&mut proto::QueryRequest)>;
    let query_cases: Vec<(&str, QueryEdit)> = vec![
        ("scope: unknown value 99", Box::new(|q| q.scope = 99)),
        ("layers: unknown value -1", Box::new(|q| q.layers = -1)),
        ("kind: unknown value 7", Box::new(|q| q.kind = 7)),
        (
            "threshold: 1.5 is outside [0, 1]",
            Box::new(|q| q.threshold = Some(1.5)),
        ),
        ("top_n: must be at least 1", Box::new(|q| q.top_n = Some(0))),
        (
            "top_n: 1000 is more than 100",
            Box::new(|q| q.top_n = Some(1000)),
        ),
        ("robot_id: required", Box::new(|q| q.robot_id.clear())),
        (
            "scope: SCOPE_LISTED needs robot_ids or maps",
            Box::new(|q| q.scope = proto::Scope::Listed as i32),
        ),
        (
            "robot_ids: only meaningful with SCOPE_LISTED",
            Box::new(|q| q.robot_ids = vec!["x".into()]),
        ),
        (
            "features: required unless keyframe_id names a stored keyframe",
            Box::new(|q| q.keyframe_id = None),
        ),
        (
            "features.global_descriptor: has 3 values but this store holds 64-value descriptors",
            Box::new(|q| {
                q.content = Some(proto::query_request::Content::Features(proto::Features {
                    global_descriptor: vec![1.0, 2.0, 3.0],
                    ..Default::default()
                }))
            }),
        ),
    ];
    for (expected, edit) in &query_cases {
        let mut q = query();
        edit(&mut q);
        let status = client.query(q).await.expect_err(expected);
        assert_eq!(
            (status.code(), status.message()),
            (Code::InvalidArgument, *expected)
        );
    }
    let mut q = query();
    q.keyframe_id = Some(4242);
    let status = client.query(q).await.unwrap_err();
    assert_eq!(status.code(), Code::NotFound);
    assert!(
        status.message().starts_with("keyframe_id: "),
        "{}",
        status.message()
    );

    // Maintenance.
    let status = client
        .erase(proto::EraseRequest {
            robot_id: "r".into(),
            session_id: "s".into(),
            keyframe_ids: vec![],
        })
        .await
        .unwrap_err();
    assert_eq!(
        (status.code(), status.message()),
        (Code::InvalidArgument, "keyframe_ids: required (empty)")
    );
    let status = client
        .reset_map(proto::ResetMapRequest {
            robot_id: "r".into(),
            session_id: "s".into(),
            map_id: None,
        })
        .await
        .unwrap_err();
    assert_eq!(
        (status.code(), status.message()),
        (Code::InvalidArgument, "map_id: required")
    );
    let status = client
        .update_poses(proto::UpdatePosesRequest {
            robot_id: "r".into(),
            session_id: "s".into(),
            updates: vec![proto::PoseUpdate {
                keyframe_id: Some(1),
                pose: None,
                map_id: None,
            }],
        })
        .await
        .unwrap_err();
    assert_eq!(
        (status.code(), status.message()),
        (Code::InvalidArgument, "updates[0].pose: required")
    );

    // A message over the transport limit is refused before it is decoded.
    let mut huge = base();
    features(&mut huge).objects[0].texts[0].text = "x".repeat(17 << 20);
    let status = client
        .insert(proto::InsertRequest {
            keyframe: Some(huge),
        })
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
    assert!(
        status.message().contains("server.max_message_bytes"),
        "{status:?}"
    );

    // Nothing changed.
    let stats = client
        .stats(proto::StatsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(stats.keyframes, 5);
}

#[tokio::test(flavor = "multi_thread")]
async fn health_and_reflection_answer() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::health_client::HealthClient;
    use tonic_health::pb::HealthCheckRequest;

    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut health = HealthClient::new(server.channel().await);
    let reply = health
        .check(HealthCheckRequest {
            service: "humem.v1.PlaceRecognition".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(reply.status(), ServingStatus::Serving);

    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    let mut reflection = ServerReflectionClient::new(server.channel().await);
    let request = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut replies = reflection
        .server_reflection_info(tokio_stream::iter([request]))
        .await
        .unwrap()
        .into_inner();
    let reply = replies.message().await.unwrap().unwrap();
    let Some(MessageResponse::ListServicesResponse(list)) = reply.message_response else {
        panic!("unexpected reflection reply");
    };
    let names: Vec<_> = list.service.iter().map(|s| s.name.as_str()).collect();
    assert!(names.contains(&"humem.v1.PlaceRecognition"), "{names:?}");
}

/// Reflection `v1alpha`, through a client nobody in this project wrote:
/// Python's `grpcio-reflection` (`tools/reflection_check.py`) lists the
/// services and describes the API's methods and a message's fields.
#[test]
fn reflection_v1alpha_lists_and_describes() {
    let python = crate::harness::models_dir().join(".venv/bin/python");
    if !python.exists() {
        eprintln!(
            "skipped: {} is absent (run scripts/setup-models.sh)",
            python.display()
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let address = server.url.trim_start_matches("http://");
    let script = crate::harness::repo_root().join("tools/reflection_check.py");
    let stdout =
        crate::harness::output_of(std::process::Command::new(&python).arg(script).arg(address));
    let lines: Vec<&str> = stdout.lines().collect();
    for expected in [
        "service humem.v1.PlaceRecognition",
        "service grpc.health.v1.Health",
        "method Insert(humem.v1.InsertRequest) -> humem.v1.InsertResponse",
        "method Query(humem.v1.QueryRequest) -> humem.v1.QueryResponse",
        "method Stats(humem.v1.StatsRequest) -> humem.v1.StatsResponse",
    ] {
        assert!(
            lines.contains(&expected),
            "{expected} missing from\n{stdout}"
        );
    }
    assert!(
        lines
            .iter()
            .any(|l| l.starts_with("field humem.v1.QueryRequest.")),
        "{stdout}"
    );
}

/// Sends raw bytes as a request body and ignores the answer's body.
#[derive(Clone, Copy)]
struct RawCodec;

struct RawEncoder;
struct RawDecoder;

impl tonic::codec::Encoder for RawEncoder {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn encode(
        &mut self,
        item: Vec<u8>,
        dst: &mut tonic::codec::EncodeBuf<'_>,
    ) -> Result<(), tonic::Status> {
        use prost::bytes::BufMut;
        dst.put_slice(&item);
        Ok(())
    }
}

impl tonic::codec::Decoder for RawDecoder {
    type Item = ();
    type Error = tonic::Status;
    fn decode(
        &mut self,
        src: &mut tonic::codec::DecodeBuf<'_>,
    ) -> Result<Option<()>, tonic::Status> {
        use prost::bytes::Buf;
        src.advance(src.remaining());
        Ok(Some(()))
    }
}

impl tonic::codec::Codec for RawCodec {
    type Encode = Vec<u8>;
    type Decode = ();
    type Encoder = RawEncoder;
    type Decoder = RawDecoder;
    fn encoder(&mut self) -> RawEncoder {
        RawEncoder
    }
    fn decoder(&mut self) -> RawDecoder {
        RawDecoder
    }
}

/// Whether `body` decodes as the request message of `rpc`.
fn decodes(rpc: &str, body: &[u8]) -> bool {
    use prost::Message;
    match rpc {
        "Insert" => proto::InsertRequest::decode(body).is_ok(),
        "InsertBatch" => proto::InsertBatchRequest::decode(body).is_ok(),
        "Query" => proto::QueryRequest::decode(body).is_ok(),
        "Erase" => proto::EraseRequest::decode(body).is_ok(),
        "ResetMap" => proto::ResetMapRequest::decode(body).is_ok(),
        "ResetSession" => proto::ResetSessionRequest::decode(body).is_ok(),
        "UpdatePoses" => proto::UpdatePosesRequest::decode(body).is_ok(),
        "Stats" => proto::StatsRequest::decode(body).is_ok(),
        "ReportVerification" => proto::ReportVerificationRequest::decode(body).is_ok(),
        _ => unreachable!("{rpc}"),
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn bodies_that_are_not_protobuf_get_invalid_argument_on_every_rpc() {
    use proptest::strategy::{Strategy, ValueTree};
    use proptest::test_runner::TestRunner;

    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut world = World::new(5, 7);
    let good = scenes::loop_drive(&mut world, "r", "s", 0, 5, 0);
    scenes::insert_all(
        &mut server.client().await,
        good.iter().map(|(kf, _)| kf.clone()),
    )
    .await;
    let mut grpc = tonic::client::Grpc::new(server.channel().await);

    // Fixed cases (field number 0, wire type 7, a varint that never ends,
    // a length past the end), then random bytes from a fixed seed.
    let mut bodies: Vec<Vec<u8>> = vec![
        vec![0x00],
        vec![0x0f, 0x01],
        vec![0xff; 11],
        vec![0x0a, 0x7f, 0x01],
    ];
    let mut runner = TestRunner::deterministic();
    let random = proptest::collection::vec(proptest::num::u8::ANY, 1..512);
    for _ in 0..64 {
        bodies.push(random.new_tree(&mut runner).unwrap().current());
    }
    let rpcs = humem_server::metrics::RPCS;
    let mut refused = 0;
    for rpc in rpcs {
        for body in &bodies {
            // Bytes that happen to decode are requests like any other.
            if decodes(rpc, body) {
                continue;
            }
            grpc.ready().await.unwrap();
            let path = tonic::codegen::http::uri::PathAndQuery::try_from(format!(
                "/humem.v1.PlaceRecognition/{rpc}"
            ))
            .unwrap();
            let status = grpc
                .unary(tonic::Request::new(body.clone()), path, RawCodec)
                .await
                .unwrap_err();
            assert_eq!(
                status.code(),
                Code::InvalidArgument,
                "{rpc} {body:?}: {status:?}"
            );
            assert!(
                status.message().contains("not a valid message"),
                "{rpc}: {status:?}"
            );
            refused += 1;
        }
    }
    // Most random bytes are not protobuf: the check did run.
    assert!(refused > rpcs.len() * 40, "{refused}");

    // Nothing changed.
    let stats = server
        .client()
        .await
        .stats(proto::StatsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(stats.keyframes, 5);
}
