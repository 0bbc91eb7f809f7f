//! Validation normalises what it accepts and names what it refuses.

use super::*;

const LIMITS: Limits = Limits {
    scene_top_k: 2,
    min_frame_gap: 100,
    top_n: 5,
};

/// A valid keyframe message (also the fuzzers' seed).
pub(crate) fn keyframe_msg() -> proto::Keyframe {
    proto::Keyframe {
        robot_id: "r".into(),
        session_id: "s".into(),
        keyframe_id: Some(0),
        frame_id: Some(0),
        timestamp: 0.5,
        map_id: Some(0),
        pose: Some(proto::Pose {
            translation: Some(proto::Vec3 {
                x: 1.0,
                y: 2.0,
                z: 3.0,
            }),
            rotation: Some(proto::Quaternion {
                w: 2.0,
                x: 0.0,
                y: 0.0,
                z: 0.0,
            }),
        }),
        content: Some(proto::keyframe::Content::Features(proto::Features {
            global_descriptor: vec![3.0, 4.0],
            appearance: vec![],
            scene: vec![
                proto::SceneClass {
                    class_id: 5,
                    probability: 0.1,
                },
                proto::SceneClass {
                    class_id: 9,
                    probability: 0.5,
                },
                proto::SceneClass {
                    class_id: 2,
                    probability: 0.3,
                },
            ],
            objects: vec![],
        })),
    }
}

#[test]
fn accepted_keyframes_are_normalised() {
    let kf = keyframe("keyframe", Some(keyframe_msg()), &LIMITS).unwrap();
    // Id 0 is a valid id when it is present.
    assert_eq!(kf.key.keyframe_id, 0);
    let Observation::Features(features) = &kf.observation else {
        panic!("features expected");
    };
    assert_eq!(features.descriptor, vec![0.6, 0.8]);
    assert_eq!(kf.pose.rotation, [1.0, 0.0, 0.0, 0.0]);
    // Most probable first, truncated to the configured top-k.
    let scene: Vec<u32> = features.scene.iter().map(|c| c.class_id).collect();
    assert_eq!(scene, vec![9, 2]);
}

#[test]
fn ids_must_be_safe_key_components() {
    let mut msg = keyframe_msg();
    msg.session_id = "a\0b".into();
    let err = keyframe("keyframe", Some(msg.clone()), &LIMITS).unwrap_err();
    assert_eq!(
        err.to_string(),
        "keyframe.session_id: contains a NUL character"
    );
    msg.session_id = "x".repeat(129);
    let err = keyframe("keyframe", Some(msg.clone()), &LIMITS).unwrap_err();
    assert_eq!(err.field, "keyframe.session_id");
}

#[test]
fn duplicate_keys_in_a_batch_are_refused() {
    let err = batch(vec![keyframe_msg(), keyframe_msg()], &LIMITS).unwrap_err();
    assert_eq!(
        err.to_string(),
        "keyframes[1].keyframe_id: the same keyframe appears twice in the batch"
    );
    assert_eq!(batch(vec![], &LIMITS).unwrap_err().field, "keyframes");
}

#[test]
fn repeated_scene_classes_are_refused() {
    let mut msg = keyframe_msg();
    if let Some(proto::keyframe::Content::Features(f)) = msg.content.as_mut() {
        f.scene[2].class_id = 5;
    }
    let err = keyframe("keyframe", Some(msg.clone()), &LIMITS).unwrap_err();
    assert_eq!(
        err.to_string(),
        "keyframe.features.scene[2].class_id: class 5 appears twice"
    );
}

#[test]
fn query_defaults_come_from_the_limits() {
    let q = proto::QueryRequest {
        robot_id: "r".into(),
        keyframe_id: Some(3),
        ..Default::default()
    };
    let spec = query(q.clone(), &LIMITS).unwrap();
    assert_eq!(spec.min_frame_gap, 100);
    assert_eq!(spec.top_n, 5);
    assert_eq!(spec.threshold, None);
    assert_eq!(spec.layers, Layers::FULL);
    assert_eq!(spec.scope, Scope::AllMaps);
    assert_eq!(spec.kind, QueryKind::LoopClosure);
}

#[test]
fn a_query_with_features_needs_a_frame_id() {
    let q = proto::QueryRequest {
        robot_id: "r".into(),
        content: Some(proto::query_request::Content::Features(proto::Features {
            global_descriptor: vec![1.0],
            ..Default::default()
        })),
        ..Default::default()
    };
    assert_eq!(
        query(q.clone(), &LIMITS).unwrap_err().to_string(),
        "frame_id: required"
    );
}

/// A valid verdict: an accepted merge with a Sim(3) estimate.
fn verdict_msg() -> proto::ReportVerificationRequest {
    proto::ReportVerificationRequest {
        robot_id: "r".into(),
        session_id: "s".into(),
        keyframe_id: Some(9),
        candidate: Some(proto::KeyframeRef {
            robot_id: "q".into(),
            session_id: String::new(),
            keyframe_id: Some(4),
        }),
        kind: proto::VerificationKind::Merge as i32,
        outcome: proto::VerificationOutcome::Accepted as i32,
        relative: Some(proto::RelativeTransform {
            pose: keyframe_msg().pose,
            scale: 0.0,
        }),
        score: Some(0.4),
        inliers: 30,
    }
}

#[test]
fn verdicts_are_normalised_and_refusals_name_the_field() {
    let v = verification(&verdict_msg()).unwrap();
    assert_eq!(v.query.keyframe_id, 9);
    assert_eq!(v.candidate.robot_id, "q");
    assert_eq!(v.kind, VerificationKind::Merge);
    assert!(v.accepted);
    // Scale 0 means 1; the rotation is normalised.
    let relative = v.relative.unwrap();
    assert_eq!(relative.scale, 1.0);
    assert_eq!(relative.pose.rotation, [1.0, 0.0, 0.0, 0.0]);
    // A rejection carries no transform.
    let mut rejected = verdict_msg();
    rejected.outcome = proto::VerificationOutcome::Rejected as i32;
    assert!(verification(&rejected).unwrap().relative.is_none());

    let refused = |change: &dyn Fn(&mut proto::ReportVerificationRequest)| {
        let mut r = verdict_msg();
        change(&mut r);
        verification(&r).unwrap_err().to_string()
    };
    assert!(refused(&|r| r.robot_id.clear()).starts_with("robot_id"));
    assert!(refused(&|r| r.keyframe_id = None).starts_with("keyframe_id: required"));
    assert!(refused(&|r| r.candidate = None).starts_with("candidate: required"));
    assert!(
        refused(&|r| r.candidate.as_mut().unwrap().keyframe_id = None)
            .starts_with("candidate.keyframe_id: required")
    );
    assert!(refused(&|r| r.kind = 0).starts_with("kind: required"));
    assert!(refused(&|r| r.kind = 9).starts_with("kind: unknown value 9"));
    assert!(refused(&|r| r.outcome = 0).starts_with("outcome: required"));
    assert!(refused(&|r| r.score = Some(1.5)).starts_with("score"));
    assert!(refused(&|r| r.relative.as_mut().unwrap().scale = -2.0).starts_with("relative.scale"));
    assert!(refused(&|r| r.relative.as_mut().unwrap().pose = None).starts_with("relative.pose"));
    // A keyframe is not its own candidate.
    assert!(refused(&|r| {
        r.candidate = Some(proto::KeyframeRef {
            robot_id: "r".into(),
            session_id: "s".into(),
            keyframe_id: Some(9),
        })
    })
    .starts_with("candidate: is the query keyframe itself"));
}
