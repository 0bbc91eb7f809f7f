//! Insert a few hundred keyframes, query, and check the ranking, the
//! eligibility rule and the scopes.

use humem_server::proto;

use crate::harness::Server;
use crate::scenes::{self, id, insert_all, query_stored, World};

fn candidate_ids(reply: &proto::QueryResponse) -> Vec<(String, u64)> {
    reply
        .candidates
        .iter()
        .map(|c| (c.robot_id.clone(), c.keyframe_id))
        .collect()
}

/// Keyframe `kf` of robot "r" at the look-alike place `look`, showing
/// `signs` (the look-alike tests' corridors differ only by their signs).
fn look_alike(look: &[f32], kf: u64, signs: Vec<proto::ObjectObservation>) -> proto::Keyframe {
    scenes::keyframe(
        "r",
        "s",
        [kf, kf * 200, 0],
        scenes::features(look.to_vec(), 0, signs),
    )
}

/// Thirty other places (keyframes 3-32) that fill the store, so a query's
/// null is known (a store smaller than `null_min_samples` calibrates
/// nothing).
fn other_places(world: &mut World) -> Vec<proto::Keyframe> {
    (3..33u64)
        .map(|place| {
            scenes::keyframe(
                "r",
                "s",
                [place, place * 200, 0],
                scenes::features(world.view(place as usize, 0.3), 1, vec![]),
            )
        })
        .collect()
}

/// A query of robot "r" by the features of `keyframe`, far from every
/// stored frame, returning the whole ranking (threshold 0).
fn query_like(keyframe: &proto::Keyframe) -> proto::QueryRequest {
    let mut query = query_stored("r", "s", 0);
    query.keyframe_id = None;
    query.frame_id = Some(50_000);
    query.threshold = Some(0.0);
    query.content = Some(proto::query_request::Content::Features(
        scenes::features_of(keyframe),
    ));
    query
}

/// The score and evidence of keyframe `kf` in `reply`.
fn score_of(reply: &proto::QueryResponse, kf: u64) -> (f32, proto::Evidence) {
    let c = reply
        .candidates
        .iter()
        .find(|c| c.keyframe_id == kf)
        .unwrap_or_else(|| panic!("keyframe {kf} not proposed: {reply:?}"));
    (c.score, c.evidence.clone().unwrap())
}

#[tokio::test(flavor = "multi_thread")]
async fn revisited_places_are_found_first_and_neighbours_are_excluded() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut client = server.client().await;
    let mut world = World::new(200, 1);
    // 200 places, then back through the first 150: 350 keyframes.
    let drive = scenes::loop_drive(&mut world, "robot-a", "s1", 0, 200, 150);
    // Some one at a time, the rest in batches.
    for (kf, _) in &drive[..20] {
        client
            .insert(proto::InsertRequest {
                keyframe: Some(kf.clone()),
            })
            .await
            .unwrap();
    }
    insert_all(&mut client, drive[20..].iter().map(|(kf, _)| kf.clone())).await;

    let mut correct = 0;
    let revisits = &drive[200..];
    for (kf, place) in revisits {
        let reply = client
            .query(query_stored("robot-a", "s1", id(kf)))
            .await
            .unwrap()
            .into_inner();
        assert!(reply.candidates.len() <= 5);
        for c in &reply.candidates {
            let gap = kf.frame_id.unwrap().abs_diff(c.frame_id);
            assert!(
                gap >= 100,
                "candidate {} is only {gap} frames away",
                c.keyframe_id
            );
            assert!(
                c.score > reply.threshold,
                "candidate below the threshold {}: {}",
                reply.threshold,
                c.score
            );
            let e = c.evidence.as_ref().unwrap();
            // The paper's Λ never falls below S_s; the calibrated score falls
            // below its scene confidence only with evidence against.
            assert!(e.raw_score >= e.scene_score - 1e-6);
            assert!(c.score >= e.scene_confidence * (1.0 - e.contradiction) - 1e-6);
        }
        let scores: Vec<f32> = reply.candidates.iter().map(|c| c.score).collect();
        assert!(
            scores.windows(2).all(|w| w[0] >= w[1]),
            "not ranked: {scores:?}"
        );
        if reply.candidates.first().map(|c| c.keyframe_id) == Some(*place as u64) {
            correct += 1;
            let top = &reply.candidates[0];
            let e = top.evidence.as_ref().unwrap();
            assert!(e.descriptor_cosine > 0.7);
            // The sign "ROOM n" is on both, at the same place in the image.
            assert_eq!(e.object_matches.len(), 1);
            assert!(e.object_score > 0.5);
            // 150 of 350 keyframes carry each text twice over: rare, but "ROOM" is
            // not a generic word, so the text counts.
            assert_eq!(e.text_matches.len(), 1, "{e:?}");
            assert_eq!(
                e.text_matches[0].candidate_text,
                format!("ROOM {}", 100 + place)
            );
        }
    }
    assert!(
        correct >= revisits.len() * 95 / 100,
        "only {correct} of {} revisits found at rank 1",
        revisits.len()
    );

    // A keyframe of the first lap has no valid match: its only near-duplicates
    // are its own neighbours, which the frame gap excludes.
    let reply = client
        .query(query_stored("robot-a", "s1", 120))
        .await
        .unwrap()
        .into_inner();
    assert!(reply.candidates.iter().all(|c| c.keyframe_id != 120));
    assert!(
        reply
            .candidates
            .iter()
            .all(|c| c.frame_id.abs_diff(360) >= 100),
        "{:?}",
        candidate_ids(&reply)
    );
    // Eligible: every keyframe at least 100 frames (34 keyframes) away.
    let expected_eligible = (0..350u64).filter(|k| (3 * k).abs_diff(360) >= 100).count();
    assert_eq!(reply.eligible_keyframes, expected_eligible as u64);

    // With no frame gap, a query with features of keyframe 120 finds 120 itself
    // only when it is asked as a frame, not as that keyframe.
    let features = scenes::features_of(&drive[120].0);
    let reply = client
        .query(proto::QueryRequest {
            robot_id: "robot-a".into(),
            session_id: "s1".into(),
            frame_id: Some(361),
            min_frame_gap: Some(0),
            content: Some(proto::query_request::Content::Features(features)),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(reply.candidates[0].keyframe_id, 120);
    let e = reply.candidates[0].evidence.as_ref().unwrap();
    assert!(e.descriptor_cosine > 0.9999, "{e:?}");
    assert!(reply.candidates[0].score > 0.95);
}

#[tokio::test(flavor = "multi_thread")]
async fn scopes_select_maps_and_robots() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut client = server.client().await;
    let mut world = World::new(40, 2);
    // Robot A maps places 0..40 in map 0 and again (a new map after a tracking
    // loss) in map 1; robot B maps them in its own map 0.
    let a0 = scenes::loop_drive(&mut world, "robot-a", "s", 0, 40, 0);
    let a1: Vec<_> = scenes::loop_drive(&mut world, "robot-a", "s", 1, 40, 0)
        .into_iter()
        .map(|(mut kf, place)| {
            kf.keyframe_id = Some(kf.keyframe_id.unwrap() + 1000);
            kf.frame_id = Some(kf.frame_id.unwrap() + 10_000);
            (kf, place)
        })
        .collect();
    let b0 = scenes::loop_drive(&mut world, "robot-b", "s", 0, 40, 0);
    for part in [&a0, &a1, &b0] {
        insert_all(&mut client, part.iter().map(|(kf, _)| kf.clone())).await;
    }

    let ask = |scope: proto::Scope, robots: Vec<String>, maps: Vec<proto::MapRef>| {
        let mut q = query_stored("robot-a", "s", 1005);
        q.scope = scope as i32;
        q.robot_ids = robots;
        q.maps = maps;
        q.top_n = Some(10);
        q.threshold = Some(0.5);
        q
    };
    let robots_and_maps = |reply: &proto::QueryResponse| -> Vec<(String, u64)> {
        reply
            .candidates
            .iter()
            .map(|c| (c.robot_id.clone(), c.map_id))
            .collect()
    };

    let same = client
        .query(ask(proto::Scope::SameMap, vec![], vec![]))
        .await
        .unwrap()
        .into_inner();
    // Map 1 holds no other view of place 5 at least 100 frames away.
    assert!(robots_and_maps(&same)
        .iter()
        .all(|m| *m == ("robot-a".into(), 1)));

    let other = client
        .query(ask(proto::Scope::OtherMaps, vec![], vec![]))
        .await
        .unwrap()
        .into_inner();
    let found = robots_and_maps(&other);
    assert!(
        found.contains(&("robot-a".into(), 0)) && found.contains(&("robot-b".into(), 0)),
        "{found:?}"
    );
    assert!(!found.contains(&("robot-a".into(), 1)));
    // Both views of place 5 come first; B's keyframe 5 is eligible with no gap.
    let top2: Vec<_> = other.candidates[..2]
        .iter()
        .map(|c| (c.robot_id.as_str(), c.keyframe_id))
        .collect();
    assert!(
        top2.contains(&("robot-a", 5)) && top2.contains(&("robot-b", 5)),
        "{top2:?}"
    );

    let listed = client
        .query(ask(proto::Scope::Listed, vec!["robot-b".into()], vec![]))
        .await
        .unwrap()
        .into_inner();
    assert!(!listed.candidates.is_empty());
    assert!(robots_and_maps(&listed).iter().all(|(r, _)| r == "robot-b"));
    assert_eq!(listed.candidates[0].keyframe_id, 5);

    let by_map = client
        .query(ask(
            proto::Scope::Listed,
            vec![],
            vec![proto::MapRef {
                robot_id: "robot-a".into(),
                session_id: None,
                map_id: 0,
            }],
        ))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(robots_and_maps(&by_map)[0], ("robot-a".into(), 0));
    assert!(robots_and_maps(&by_map)
        .iter()
        .all(|m| *m == ("robot-a".into(), 0)));
    assert_eq!(by_map.eligible_keyframes, 40);
}

#[tokio::test(flavor = "multi_thread")]
async fn distinctive_text_tells_look_alike_places_apart() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut client = server.client().await;
    let mut world = World::new(33, 3);
    // Two corridors that look the same; only the shop sign differs.
    let look = world.view(0, 0.0);
    let corridor = |kf: u64, text: &str| look_alike(&look, kf, vec![scenes::sign(text, 0.5, 0.4)]);
    let others = other_places(&mut world);
    insert_all(
        &mut client,
        [
            corridor(1, "ACME BAKERY 221"),
            corridor(2, "LUNA BAKERY 48"),
        ]
        .into_iter()
        .chain(others),
    )
    .await;
    let mut query = query_like(&corridor(9, "LUNA BAKERY 48"));

    let full = client.query(query.clone()).await.unwrap().into_inner();
    assert_eq!(full.candidates[0].keyframe_id, 2);
    let (matching, e) = score_of(&full, 2);
    assert!(e.text_score > 0.8 && e.text_distinctiveness > 0.0, "{e:?}");
    assert_eq!(e.text_matches[0].candidate_text, "LUNA BAKERY 48");
    assert_eq!(e.contradiction, 0.0);
    assert!(e.null_samples >= 30 && e.scene_confidence > 0.9, "{e:?}");
    // The look-alike with the other shop's sign: the texts contradict.
    let (contradicted, e) = score_of(&full, 1);
    assert!(e.contradiction > 0.3 && e.text_contradiction > 0.3, "{e:?}");
    assert_eq!(e.text_conflicts.len(), 1);
    assert_eq!(e.text_conflicts[0].query_text, "LUNA BAKERY 48");
    assert_eq!(e.text_conflicts[0].candidate_text, "ACME BAKERY 221");
    assert!(contradicted < matching);
    // Its calibrated score went down from the scene score, not merely failed to rise.
    assert!(
        contradicted < e.scene_confidence - 0.2,
        "{contradicted} {e:?}"
    );
    // At the default threshold only the matching corridor is proposed.
    let mut at_default = query.clone();
    at_default.threshold = None;
    let answer = client.query(at_default).await.unwrap().into_inner();
    let ids: Vec<u64> = answer.candidates.iter().map(|c| c.keyframe_id).collect();
    assert_eq!(ids, vec![2], "threshold {}", answer.threshold);

    // The paper's fusion (evidence for only) scores the same pair higher:
    // the text merely fails to add there.
    query.layers = proto::Layers::FullSupportOnly as i32;
    let paper = client.query(query.clone()).await.unwrap().into_inner();
    let (supported_only, e) = score_of(&paper, 1);
    assert_eq!(e.contradiction, 0.0);
    assert!(
        contradicted < supported_only - 0.2,
        "{contradicted} vs {supported_only}"
    );
    assert!(supported_only >= e.scene_confidence - 1e-6);

    // SCAL alone cannot tell them apart; the layer switch is honoured.
    query.layers = proto::Layers::Scal as i32;
    let scal = client.query(query).await.unwrap().into_inner();
    let (a, _) = score_of(&scal, 1);
    let (b, e) = score_of(&scal, 2);
    assert_eq!(a, b);
    assert_eq!(
        (e.object_score, e.text_score, e.contradiction),
        (0.0, 0.0, 0.0)
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn a_generic_sign_where_a_distinctive_one_should_be_speaks_against() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut client = server.client().await;
    let mut world = World::new(33, 3);
    // Two look-alike corridors: one with the query's street-name sign beside
    // its STOP sign, one where only the STOP sign is read (the other sign
    // is not there). The street-name sign is small (2 % of the image), but
    // the second corridor read text right beside its place, so it would
    // have read it too.
    let look = world.view(0, 0.0);
    let both = || {
        vec![
            scenes::sign("KING AVE", 0.8, 0.25),
            scenes::sign("STOP", 0.84, 0.35),
        ]
    };
    let others = other_places(&mut world);
    insert_all(
        &mut client,
        [
            look_alike(&look, 1, vec![scenes::sign("STOP", 0.84, 0.35)]),
            look_alike(&look, 2, both()),
        ]
        .into_iter()
        .chain(others),
    )
    .await;
    let mut query = query_like(&look_alike(&look, 9, both()));
    let full = client.query(query.clone()).await.unwrap().into_inner();
    assert_eq!(full.candidates[0].keyframe_id, 2);
    let (matching, e) = score_of(&full, 2);
    assert_eq!(e.contradiction, 0.0, "{e:?}");
    let (without_sign, e) = score_of(&full, 1);
    // KING AVE is missing, STOP is not.
    // In a store of 32 keyframes STOP is in 2 (rarity ln 16 / ln 32 = 0.8):
    // D = 0.466667 · 0.9 · 0.05 = 0.021; KING AVE is in 1: D = 0.591667.
    // X_o = 0.591667 · 0.9 / ((0.591667 + 0.021) · 0.9) = 0.965724.
    assert!((e.object_absence - 0.965724).abs() < 1e-4, "{e:?}");
    assert_eq!(e.missing_objects.len(), 1);
    assert!(e.missing_objects[0].in_query);
    assert_eq!(e.missing_objects[0].class_name, "sign");
    assert!(without_sign < matching);
    assert!(
        without_sign < e.scene_confidence * (1.0 - 0.5 * 0.96) + 0.05,
        "{without_sign} {e:?}"
    );
    // Without the evidence against, the two corridors are nearly alike.
    query.layers = proto::Layers::FullSupportOnly as i32;
    let paper = client.query(query).await.unwrap().into_inner();
    let (supported_only, e) = score_of(&paper, 1);
    assert_eq!(e.object_absence, 0.0);
    assert!(
        without_sign < supported_only - 0.3,
        "{without_sign} vs {supported_only}"
    );
}

/// The whole ranking (threshold 0, up to 50) for stored keyframe 300 of
/// robot "r" in `scope`, from a server started with `env` holding
/// `keyframes`.
async fn whole_ranking_of_300(
    env: &[&str],
    keyframes: &[proto::Keyframe],
    scope: proto::Scope,
) -> proto::QueryResponse {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with(dir.path(), env);
    let mut client = server.client().await;
    insert_all(&mut client, keyframes.to_vec()).await;
    let mut query = query_stored("r", "s", 300);
    query.scope = scope as i32;
    query.threshold = Some(0.0);
    query.top_n = Some(50);
    client.query(query).await.unwrap().into_inner()
}

/// `kf` with its camera turned by `yaw_deg` about the map's z axis.
fn turned(mut kf: proto::Keyframe, yaw_deg: f64) -> proto::Keyframe {
    let h = yaw_deg.to_radians() / 2.0;
    kf.pose.as_mut().unwrap().rotation = Some(proto::Quaternion {
        w: h.cos(),
        x: 0.0,
        y: 0.0,
        z: h.sin(),
    });
    kf
}

/// The place of a loop query seen again in its own map with the camera
/// turned 90° (a view across a junction: left out), turned 20° (kept),
/// and turned 90° in another map (kept: the maps' frames are unrelated);
/// with `vpr.max_view_change_deg = 180` nothing is left out.
#[tokio::test(flavor = "multi_thread")]
async fn a_loop_query_leaves_out_views_of_its_map_turned_away_from_it() {
    let mut world = World::new(40, 5);
    let place = world.view(0, 0.0);
    let mut keyframes = other_places(&mut world);
    keyframes.push(turned(look_alike(&place, 1, vec![]), 90.0));
    keyframes.push(turned(look_alike(&place, 2, vec![]), 20.0));
    keyframes.push(turned(
        scenes::keyframe(
            "r",
            "s",
            [40, 8_000, 1],
            scenes::features(place.clone(), 0, vec![]),
        ),
        90.0,
    ));
    // The query is back at the place (x = 2) after driving on to x = 32:
    // within the map's drift of keyframes 1 and 2.
    let mut back = look_alike(&place, 300, vec![]);
    back.pose = Some(scenes::pose(2.0));
    keyframes.push(back);

    for (env, left_out) in [
        (&[][..], true),
        (&["HUMEM_VPR__MAX_VIEW_CHANGE_DEG=180"][..], false),
    ] {
        let reply = whole_ranking_of_300(env, &keyframes, proto::Scope::AllMaps).await;
        let ids: Vec<u64> = reply.candidates.iter().map(|c| c.keyframe_id).collect();
        assert!(ids.contains(&2) && ids.contains(&40), "{env:?}: {ids:?}");
        assert_eq!(ids.contains(&1), !left_out, "{env:?}: {ids:?}");
        if !left_out {
            assert_eq!(
                &ids[..3]
                    .iter()
                    .copied()
                    .collect::<std::collections::BTreeSet<_>>(),
                &[1, 2, 40].into()
            );
        }
    }
}

/// A drive along x (keyframe k at x = k, 1 to 32) back to its start:
/// keyframe 300, at x = 1, looks like keyframe 1 (the place's first
/// visit, 0 away after a path of 62) and like keyframe 20 (a look-alike 19
/// away after a path of 43: past twice 0.05 · 43 + 3, the radius being
/// three keyframe spacings of 1). The look-alike loses the envelope's
/// whole penalty (0.1) and the first visit nothing, each with the
/// envelope's numbers; with `vpr.max_drift_ratio = 1` neither loses any.
#[tokio::test(flavor = "multi_thread")]
async fn a_loop_query_lowers_a_look_alike_farther_than_the_maps_drift() {
    let mut world = World::new(40, 5);
    let place = world.view(0, 0.0);
    let mut keyframes: Vec<proto::Keyframe> = other_places(&mut world)
        .into_iter()
        .filter(|kf| id(kf) != 20)
        .collect();
    keyframes.push(look_alike(&place, 1, vec![]));
    keyframes.push(scenes::keyframe(
        "r",
        "s",
        [2, 400, 0],
        scenes::features(world.view(2, 0.3), 1, vec![]),
    ));
    keyframes.push(look_alike(&place, 20, vec![]));
    let mut back = look_alike(&place, 300, vec![]);
    back.pose = Some(scenes::pose(1.0));
    keyframes.push(back);

    let mut look_alike_scores = Vec::new();
    for (env, bound) in [
        (&[][..], 0.05),
        (&["HUMEM_VPR__MAX_DRIFT_RATIO=1"][..], 1.0),
    ] {
        let reply = whole_ranking_of_300(env, &keyframes, proto::Scope::SameMap).await;
        let ids: Vec<u64> = reply.candidates.iter().map(|c| c.keyframe_id).collect();
        let drift_of = |id: u64| {
            let candidate = reply.candidates.iter().find(|c| c.keyframe_id == id);
            let drift = candidate
                .and_then(|c| c.evidence.as_ref())
                .and_then(|e| e.drift)
                .unwrap_or_else(|| panic!("{env:?}: keyframe {id}, with the envelope: {ids:?}"));
            (candidate.unwrap().score, drift)
        };
        let (_, first_visit) = drift_of(1);
        assert_eq!(first_visit.distance, 0.0);
        assert!((first_visit.path - 62.0).abs() < 1e-9, "{first_visit:?}");
        assert_eq!(first_visit.ratio, 0.0);
        assert!(
            (first_visit.allowance - (bound * 62.0 + 3.0)).abs() < 1e-9,
            "{first_visit:?}"
        );
        assert_eq!(first_visit.penalty, 0.0);
        let (score, look) = drift_of(20);
        assert!((look.distance - 19.0).abs() < 1e-9, "{look:?}");
        assert!((look.path - 43.0).abs() < 1e-9, "{look:?}");
        let expected = if bound < 1.0 { 0.1 } else { 0.0 };
        assert!((look.penalty - expected).abs() < 1e-6, "{env:?}: {look:?}");
        look_alike_scores.push(score);
    }
    // Lowered by the penalty, and by nothing else.
    assert!(
        (look_alike_scores[1] - look_alike_scores[0] - 0.1).abs() < 1e-5,
        "{look_alike_scores:?}"
    );
}
