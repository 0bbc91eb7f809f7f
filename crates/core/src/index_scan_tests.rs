//! The index's partitioned scan against the full scan: for every scope and
//! read-access rule, a query visits only the rows of the maps it may see
//! and gets the full scan's answer bit for bit, in both passes.

use proptest::prelude::*;

use crate::engine::filter::RowFilter;
use crate::index::Index;
use crate::keyframe::{Features, KeyframeKey, Pose, SceneClass, SemanticKeyframe, SessionKey};
use crate::vpr::eligibility::{QueryContext, Scope};
use crate::vpr::params::{ScanMode, VprParams};
use crate::vpr::scal::ScalQuery;
use crate::vpr::scan::{scal_scan, ScalScan};
use crate::vpr::testing::{scene_strategy, scope_strategy, unit_vector};

const ROBOTS: &[&str] = &["r0", "r1", "r2", "r3", "r4", "r5"];
const SESSIONS: &[&str] = &["s0", "s1"];

fn keyframe(
    robot: usize,
    session: usize,
    map: u64,
    id: u64,
    features: Features,
) -> SemanticKeyframe {
    SemanticKeyframe {
        key: KeyframeKey {
            robot_id: ROBOTS[robot].into(),
            session_id: SESSIONS[session].into(),
            keyframe_id: id,
        },
        frame_id: id * 3,
        timestamp: id as f64,
        map_id: map,
        pose: Pose::default(),
        features,
    }
}

/// A robot name, sometimes one the store has never seen.
fn robot_name() -> impl Strategy<Value = String> {
    prop::sample::select(ROBOTS).prop_map(str::to_string)
}

fn assert_same_bits(a: &ScalScan, b: &ScalScan) -> Result<(), TestCaseError> {
    prop_assert_eq!(a.eligible, b.eligible);
    prop_assert_eq!(a.null.samples, b.null.samples);
    prop_assert_eq!(a.null.location.to_bits(), b.null.location.to_bits());
    let key = |s: &ScalScan| -> Vec<(usize, u32, u32, usize)> {
        s.hits
            .iter()
            .map(|h| (h.row, h.score.to_bits(), h.cosine.to_bits(), h.depth))
            .collect()
    };
    prop_assert_eq!(key(a), key(b));
    Ok(())
}

/// One stored keyframe: robot, session, map, keyframe id, descriptor,
/// scene.
type StoredRow = (usize, usize, u64, u64, Vec<f32>, Vec<SceneClass>);

/// 5 robots (r5 never stores), each in 2 sessions of up to 3 maps.
fn store_strategy() -> impl Strategy<Value = Vec<StoredRow>> {
    prop::collection::vec(
        (
            0usize..5,
            0usize..2,
            0u64..3,
            0u64..40,
            unit_vector(6),
            scene_strategy(),
        ),
        1..150,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    #[test]
    fn a_query_scans_only_what_it_may_see_and_answers_as_the_full_scan(
        rows in store_strategy(),
        query in (0usize..6, 0usize..2, prop::option::of(0u64..40), 0u64..120, 0u64..3, 0u64..40),
        scope in scope_strategy(ROBOTS, SESSIONS),
        readable in prop::option::of(prop::collection::vec(robot_name(), 0..4)),
        history in prop::collection::vec((unit_vector(6), scene_strategy()), 1..4),
        k in 1usize..12,
    ) {
        let mut index = Index::new(6);
        for (robot, session, map, id, descriptor, scene) in rows {
            let features = Features { descriptor, scene, ..Features::default() };
            index.upsert(keyframe(robot, session, map, id, features));
        }
        let (robot, session, keyframe_id, frame_id, map_id, min_frame_gap) = query;
        let context = QueryContext {
            session: SessionKey {
                robot_id: ROBOTS[robot].into(),
                session_id: SESSIONS[session].into(),
            },
            keyframe_id,
            frame_id,
            map_id,
            min_frame_gap,
            scope,
            readable_robots: readable,
        };
        let history: Vec<Features> = history
            .into_iter()
            .map(|(descriptor, scene)| Features { descriptor, scene, ..Features::default() })
            .collect();
        let query = ScalQuery { history: history.iter().collect() };
        let filter = index.eligibility(&context);
        if let Some(rows) = filter.partition() {
            // The partition holds every eligible row, and no more than its
            // share of the store.
            prop_assert!(rows.windows(2).all(|w| w[0] < w[1]));
            prop_assert!(rows.len() as f64 <= crate::index::PARTITION_MAX_SHARE * index.len() as f64);
            for row in (0..index.len()).filter(|&r| filter.test(r)) {
                prop_assert!(rows.binary_search(&row).is_ok(), "eligible row {} left out", row);
            }
        }
        for mode in [ScanMode::Exact, ScanMode::Compressed] {
            let params = VprParams { top_k: k, scan: mode, ..VprParams::default() };
            let parted = scal_scan(&params, &query, &index, &filter);
            let full = scal_scan(&params, &query, &index, &filter.clone().without_partition());
            assert_same_bits(&parted, &full)?;
        }
    }
}

#[test]
fn a_robots_own_map_is_a_partition_and_the_whole_fleet_is_not() {
    let mut index = Index::new(6);
    for robot in 0..5 {
        for id in 0..20 {
            let mut descriptor = vec![0.0; 6];
            descriptor[robot] = 1.0;
            let features = Features {
                descriptor,
                ..Features::default()
            };
            index.upsert(keyframe(robot, 0, id % 2, id, features));
        }
    }
    let context = |scope: Scope, readable: Option<Vec<String>>| QueryContext {
        session: SessionKey {
            robot_id: "r1".into(),
            session_id: "s0".into(),
        },
        keyframe_id: None,
        frame_id: 0,
        map_id: 1,
        min_frame_gap: 0,
        scope,
        readable_robots: readable,
    };
    let same_map = index.eligibility(&context(Scope::SameMap, None));
    let rows = same_map.partition().expect("one map of five robots");
    assert_eq!(rows.len(), 10);
    assert!(rows.iter().all(|&r| {
        let meta = index.meta(r);
        meta.key.robot_id == "r1" && meta.map_id == 1
    }));
    // Read access alone narrows the whole fleet to a partition.
    let own = index.eligibility(&context(Scope::AllMaps, Some(vec!["r1".into()])));
    assert_eq!(own.partition().map(<[usize]>::len), Some(20));
    assert!(index
        .eligibility(&context(Scope::AllMaps, None))
        .partition()
        .is_none());
    assert!(index
        .eligibility(&context(Scope::OtherMaps, None))
        .partition()
        .is_none());
}
