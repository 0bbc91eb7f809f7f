//! Erase, map reset, session reset and pose updates change what queries see
//! and persist across a restart.

use humem_server::proto;

use crate::harness::Server;
use crate::scenes::{self, World};

#[tokio::test(flavor = "multi_thread")]
async fn maintenance_persists() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut client = server.client().await;
    let mut world = World::new(30, 6);
    let map0 = scenes::loop_drive(&mut world, "r", "s1", 0, 30, 0);
    let map1: Vec<_> = scenes::loop_drive(&mut world, "r", "s1", 1, 30, 0)
        .into_iter()
        .map(|(mut kf, p)| {
            kf.keyframe_id = Some(100 + kf.keyframe_id.unwrap());
            (kf, p)
        })
        .collect();
    let other_session = scenes::loop_drive(&mut world, "r", "s2", 0, 30, 0);
    for part in [&map0, &map1, &other_session] {
        scenes::insert_all(&mut client, part.iter().map(|(kf, _)| kf.clone())).await;
    }

    let erased = client
        .erase(proto::EraseRequest {
            robot_id: "r".into(),
            session_id: "s1".into(),
            keyframe_ids: vec![0, 1, 2, 999],
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(erased.erased, 3);
    let reset = client
        .reset_map(proto::ResetMapRequest {
            robot_id: "r".into(),
            session_id: "s1".into(),
            map_id: Some(1),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(reset.erased, 30);
    let reset = client
        .reset_session(proto::ResetSessionRequest {
            robot_id: "r".into(),
            session_id: "s2".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(reset.erased, 30);
    // A loop correction moves keyframe 10 and merges it into map 7.
    let moved = proto::Pose {
        translation: Some(proto::Vec3 {
            x: 1.0,
            y: 2.0,
            z: 3.0,
        }),
        rotation: Some(proto::Quaternion {
            w: 0.0,
            x: 0.0,
            y: 0.0,
            z: 2.0,
        }),
    };
    let updated = client
        .update_poses(proto::UpdatePosesRequest {
            robot_id: "r".into(),
            session_id: "s1".into(),
            updates: vec![
                proto::PoseUpdate {
                    keyframe_id: Some(10),
                    pose: Some(moved),
                    map_id: Some(7),
                },
                proto::PoseUpdate {
                    keyframe_id: Some(555),
                    pose: Some(moved),
                    map_id: None,
                },
            ],
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(updated.updated, 1);
    assert_eq!(updated.missing_keyframe_ids, vec![555]);

    let server = server.restart();
    let mut client = server.client().await;
    let stats = client
        .stats(proto::StatsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(stats.keyframes, 27);
    let maps: Vec<_> = stats
        .maps
        .iter()
        .map(|m| (m.session_id.as_str(), m.map_id, m.keyframes))
        .collect();
    assert_eq!(maps, vec![("s1", 0, 26), ("s1", 7, 1)]);

    // Keyframe 10 is found where the correction put it, with a unit quaternion.
    let features = scenes::features_of(&map0[10].0);
    let reply = client
        .query(proto::QueryRequest {
            robot_id: "other-robot".into(),
            frame_id: Some(0),
            content: Some(proto::query_request::Content::Features(features)),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    let top = &reply.candidates[0];
    assert_eq!((top.keyframe_id, top.map_id), (10, 7));
    let pose = top.pose.as_ref().unwrap();
    assert_eq!(pose.translation.as_ref().unwrap().z, 3.0);
    assert_eq!(pose.rotation.as_ref().unwrap().z, 1.0);
    // Erased keyframes are gone from answers too.
    assert!(reply
        .candidates
        .iter()
        .all(|c| c.keyframe_id > 2 && c.keyframe_id < 100));
}
