//! Structured fuzzing of request decoding and validation (stable Rust,
//! proptest): valid requests of every RPC, encoded, then mutated (bytes
//! flipped, inserted, deleted, the message cut short or spliced with
//! another), decoded and validated. Whatever the bytes, decoding fails
//! cleanly or validation answers Ok or a named field: nothing panics, and a
//! validated request keeps what validation promises.
//!
//! CI runs proptest's default number of cases; a longer run:
//! `PROPTEST_CASES=200000 cargo test --release -p humem-server --lib fuzz`.

use proptest::prelude::*;
use prost::Message;

use super::validate::{self, Limits};
use crate::proto;

const LIMITS: Limits = Limits {
    scene_top_k: 16,
    min_frame_gap: 100,
    top_n: 5,
};

fn features() -> proto::Features {
    proto::Features {
        global_descriptor: (0..16).map(|i| (i as f32 * 0.37).sin()).collect(),
        scene: vec![proto::SceneClass {
            class_id: 3,
            probability: 0.7,
        }],
        objects: vec![proto::ObjectObservation {
            class_name: "sign".into(),
            confidence: 0.9,
            x: 0.3,
            y: 0.4,
            area: 0.02,
            texts: vec![proto::TextObservation {
                text: "ROOM 101".into(),
                confidence: 0.8,
            }],
        }],
        appearance: vec![],
    }
}

fn keyframe() -> proto::Keyframe {
    proto::Keyframe {
        robot_id: "car-1".into(),
        keyframe_id: Some(7),
        content: Some(proto::keyframe::Content::Features(features())),
        ..validate::tests::keyframe_msg()
    }
}

/// One valid request of every RPC, encoded, with the RPC's name.
fn seeds() -> Vec<(&'static str, Vec<u8>)> {
    let mut image_keyframe = keyframe();
    image_keyframe.keyframe_id = Some(8);
    image_keyframe.content = Some(proto::keyframe::Content::Image(proto::Image {
        encoding: proto::image::Encoding::Gray8 as i32,
        data: vec![128; 64 * 48],
        width: 64,
        height: 48,
        stride: 64,
    }));
    vec![
        (
            "Insert",
            proto::InsertRequest {
                keyframe: Some(keyframe()),
            }
            .encode_to_vec(),
        ),
        (
            "InsertBatch",
            proto::InsertBatchRequest {
                keyframes: vec![keyframe(), image_keyframe],
            }
            .encode_to_vec(),
        ),
        (
            "Query",
            proto::QueryRequest {
                robot_id: "car-1".into(),
                session_id: "s".into(),
                frame_id: Some(300),
                map_id: Some(0),
                predecessor_keyframe_ids: vec![6, 5],
                scope: proto::Scope::Listed as i32,
                robot_ids: vec!["car-2".into()],
                maps: vec![proto::MapRef {
                    robot_id: "car-3".into(),
                    session_id: Some("x".into()),
                    map_id: 2,
                }],
                top_n: Some(3),
                threshold: Some(0.5),
                content: Some(proto::query_request::Content::Features(features())),
                ..Default::default()
            }
            .encode_to_vec(),
        ),
        (
            "Erase",
            proto::EraseRequest {
                robot_id: "car-1".into(),
                session_id: "s".into(),
                keyframe_ids: vec![1, 2, 3],
            }
            .encode_to_vec(),
        ),
        (
            "UpdatePoses",
            proto::UpdatePosesRequest {
                robot_id: "car-1".into(),
                session_id: "s".into(),
                updates: vec![proto::PoseUpdate {
                    keyframe_id: Some(7),
                    pose: keyframe().pose,
                    map_id: Some(1),
                }],
            }
            .encode_to_vec(),
        ),
        (
            "ReportVerification",
            proto::ReportVerificationRequest {
                robot_id: "car-1".into(),
                session_id: "s".into(),
                keyframe_id: Some(9),
                candidate: Some(proto::KeyframeRef {
                    robot_id: "car-2".into(),
                    session_id: "t".into(),
                    keyframe_id: Some(4),
                }),
                kind: proto::VerificationKind::Merge as i32,
                outcome: proto::VerificationOutcome::Accepted as i32,
                relative: Some(proto::RelativeTransform {
                    pose: keyframe().pose,
                    scale: 1.5,
                }),
                score: Some(0.7),
                inliers: 40,
            }
            .encode_to_vec(),
        ),
    ]
}

/// One change to a message's bytes.
#[derive(Debug, Clone)]
enum Mutation {
    Flip(usize, u8),
    Insert(usize, u8),
    Delete(usize),
    Truncate(usize),
    Splice(usize, usize, usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<usize>(), 1u8..=255).prop_map(|(at, bits)| Mutation::Flip(at, bits)),
        (any::<usize>(), any::<u8>()).prop_map(|(at, b)| Mutation::Insert(at, b)),
        any::<usize>().prop_map(Mutation::Delete),
        any::<usize>().prop_map(Mutation::Truncate),
        (any::<usize>(), any::<usize>(), any::<usize>())
            .prop_map(|(seed, from, at)| Mutation::Splice(seed, from, at)),
    ]
}

fn mutate(mut bytes: Vec<u8>, mutations: &[Mutation], seeds: &[(&str, Vec<u8>)]) -> Vec<u8> {
    for m in mutations {
        let n = bytes.len().max(1);
        match *m {
            Mutation::Flip(at, bits) if !bytes.is_empty() => bytes[at % n] ^= bits,
            Mutation::Insert(at, b) => bytes.insert(at % (bytes.len() + 1), b),
            Mutation::Delete(at) if !bytes.is_empty() => {
                bytes.remove(at % n);
            }
            Mutation::Truncate(at) => bytes.truncate(at % (bytes.len() + 1)),
            Mutation::Splice(seed, from, at) => {
                let other = &seeds[seed % seeds.len()].1;
                let from = from % (other.len() + 1);
                let at = at % (bytes.len() + 1);
                bytes.splice(at..at, other[from..].iter().copied());
            }
            _ => {}
        }
    }
    bytes
}

/// Decodes and validates `bytes` as the request of `rpc`; panics only if
/// validation broke one of its promises.
fn decode_and_validate(rpc: &str, bytes: &[u8]) {
    match rpc {
        "Insert" => {
            if let Ok(r) = proto::InsertRequest::decode(bytes) {
                if let Ok(k) = validate::keyframe("keyframe", r.keyframe, &LIMITS) {
                    assert!(!k.key.robot_id.is_empty());
                }
            }
        }
        "InsertBatch" => {
            if let Ok(r) = proto::InsertBatchRequest::decode(bytes) {
                let n = r.keyframes.len();
                if let Ok(batch) = validate::batch(r.keyframes, &LIMITS) {
                    assert_eq!(batch.len(), n);
                }
            }
        }
        "Query" => {
            if let Ok(r) = proto::QueryRequest::decode(bytes) {
                if let Ok(spec) = validate::query(r, &LIMITS) {
                    assert!(spec.top_n >= 1);
                    assert!(spec.threshold.is_none_or(|t| (0.0..=1.0).contains(&t)));
                }
            }
        }
        "Erase" => {
            if let Ok(r) = proto::EraseRequest::decode(bytes) {
                let _ = validate::erase(&r);
            }
        }
        "UpdatePoses" => {
            if let Ok(r) = proto::UpdatePosesRequest::decode(bytes) {
                let _ = validate::pose_updates(&r);
            }
        }
        "ReportVerification" => {
            if let Ok(r) = proto::ReportVerificationRequest::decode(bytes) {
                let _ = validate::verification(&r);
            }
        }
        other => unreachable!("{other}"),
    }
}

#[test]
fn the_seeds_are_valid_requests() {
    for (rpc, bytes) in seeds() {
        match rpc {
            "Insert" => {
                let r = proto::InsertRequest::decode(&bytes[..]).unwrap();
                validate::keyframe("keyframe", r.keyframe, &LIMITS).unwrap();
            }
            "InsertBatch" => {
                let r = proto::InsertBatchRequest::decode(&bytes[..]).unwrap();
                validate::batch(r.keyframes, &LIMITS).unwrap();
            }
            "Query" => {
                validate::query(proto::QueryRequest::decode(&bytes[..]).unwrap(), &LIMITS).unwrap();
            }
            "Erase" => {
                validate::erase(&proto::EraseRequest::decode(&bytes[..]).unwrap()).unwrap();
            }
            "UpdatePoses" => {
                validate::pose_updates(&proto::UpdatePosesRequest::decode(&bytes[..]).unwrap())
                    .unwrap();
            }
            "ReportVerification" => {
                let r = proto::ReportVerificationRequest::decode(&bytes[..]).unwrap();
                let v = validate::verification(&r).unwrap();
                assert_eq!(v.relative.map(|t| t.scale), Some(1.5));
            }
            _ => unreachable!(),
        }
    }
}

proptest! {
    #[test]
    fn fuzz_mutated_requests_decode_and_validate_without_panicking(
        seed in any::<usize>(),
        mutations in prop::collection::vec(mutation(), 1..8),
    ) {
        let seeds = seeds();
        let (rpc, bytes) = &seeds[seed % seeds.len()];
        let bytes = mutate(bytes.clone(), &mutations, &seeds);
        decode_and_validate(rpc, &bytes);
    }

    #[test]
    fn fuzz_random_bytes_decode_and_validate_without_panicking(
        rpc in prop::sample::select(vec!["Insert", "InsertBatch", "Query", "Erase", "UpdatePoses", "ReportVerification"]),
        bytes in prop::collection::vec(any::<u8>(), 0..512),
    ) {
        decode_and_validate(rpc, &bytes);
    }
}
