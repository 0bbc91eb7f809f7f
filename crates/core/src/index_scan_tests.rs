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
use crate::vpr::testing::{features_of, scene_strategy, scope_strategy, unit_vector};

pub(crate) const ROBOTS: &[&str] = &["r0", "r1", "r2", "r3", "r4", "r5"];
pub(crate) const SESSIONS: &[&str] = &["s0", "s1"];

pub(crate) fn keyframe(
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

/// Who asks a random query: robot and session (indices into [`ROBOTS`] and
/// [`SESSIONS`]), keyframe id, frame id, map id and frame gap.
pub(crate) type Asker = (usize, usize, Option<u64>, u64, u64, u64);

/// The context of a query `asker` makes with `scope` and `readable`.
pub(crate) fn context_of(
    asker: Asker,
    scope: Scope,
    readable: Option<Vec<String>>,
) -> QueryContext {
    let (robot, session, keyframe_id, frame_id, map_id, min_frame_gap) = asker;
    QueryContext {
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
pub(crate) type StoredRow = (usize, usize, u64, u64, Vec<f32>, Vec<SceneClass>);

/// 5 robots (r5 never stores), each in 2 sessions of up to 3 maps.
pub(crate) fn store_strategy() -> impl Strategy<Value = Vec<StoredRow>> {
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
        let context = context_of(query, scope, readable);
        let history = features_of(history);
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

#[test]
fn a_partitions_tagged_rows_are_the_same_from_its_maps_sampled_subsets() {
    let mut index = Index::new(6);
    for robot in 0..3 {
        for id in 0..3_000 {
            let features = Features {
                descriptor: unit_descriptor(robot, id),
                ..Features::default()
            };
            index.upsert(keyframe(robot, 0, id % 2, id, features));
        }
    }
    // Erasures fill holes with other rows, and moves change maps.
    for id in (0..3_000).step_by(7) {
        index.remove(&KeyframeKey {
            robot_id: "r1".into(),
            session_id: "s0".into(),
            keyframe_id: id,
        });
    }
    for id in (1..3_000).step_by(11) {
        let key = KeyframeKey {
            robot_id: "r1".into(),
            session_id: "s0".into(),
            keyframe_id: id,
        };
        index.update_pose(&key, Pose::default(), Some(0));
    }
    let context = |scope: Scope| QueryContext {
        session: SessionKey {
            robot_id: "r1".into(),
            session_id: "s0".into(),
        },
        keyframe_id: None,
        frame_id: 0,
        map_id: 1,
        min_frame_gap: 0,
        scope,
        readable_robots: Some(vec!["r1".into()]),
    };
    let tag = |row: usize| crate::vpr::memory::KeyframeMemory::sample_tag(&index, row);
    for scope in [Scope::SameMap, Scope::OtherMaps, Scope::AllMaps] {
        for bits in 0..8 {
            let mask = (1u32 << bits) - 1;
            let mut walked = Vec::new();
            let partitioned = index
                .eligibility(&context(scope.clone()))
                .for_each_tagged_in_partition(mask, &tag, &mut |row| walked.push(row));
            assert!(partitioned, "{scope:?}");
            walked.sort_unstable();
            let gathered = index.eligibility(&context(scope.clone()));
            let expected: Vec<usize> = gathered
                .partition()
                .unwrap()
                .iter()
                .copied()
                .filter(|&row| tag(row) & mask == 0)
                .collect();
            assert!(bits < 6 || !expected.is_empty());
            assert_eq!(walked, expected, "{scope:?}, mask {mask}");
        }
    }
}

/// A unit descriptor, different for each robot and keyframe.
fn unit_descriptor(robot: usize, id: u64) -> Vec<f32> {
    let mut descriptor = [0.1f32; 6];
    descriptor[robot] = 1.0;
    descriptor[5] = (id % 13) as f32 / 13.0;
    let norm = descriptor.iter().map(|x| x * x).sum::<f32>().sqrt();
    descriptor.iter().map(|x| x / norm).collect()
}

/// The index of `rows`, keeping a neighbour graph when `graph` is given:
/// the last `graph` rows stored wait to enter it (as the store's writer
/// leaves the newest keyframes until it adds them).
pub(crate) fn index_of(rows: Vec<StoredRow>, graph: Option<usize>) -> Index {
    let mut index = Index::new(6);
    if graph.is_some() {
        index.keep_neighbour_graph(None).unwrap();
        // Every map its own graph too.
        index.keep_map_graphs(1);
    }
    let deferred_from = rows.len().saturating_sub(graph.unwrap_or(0));
    for (i, (robot, session, map, id, descriptor, scene)) in rows.into_iter().enumerate() {
        if graph.is_some() && i == deferred_from {
            index.defer_graph_inserts();
        }
        let features = Features {
            descriptor,
            scene,
            ..Features::default()
        };
        index.upsert(keyframe(robot, session, map, id, features));
    }
    index
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// With the neighbour graph's candidates, a query still gets only rows
    /// it may see; where the planner (or the query) chooses a full pass,
    /// the answer is the one without a graph, bit for bit.
    #[test]
    fn the_graph_proposes_only_what_a_query_may_see_and_exact_passes_are_unchanged(
        rows in store_strategy(),
        removed in prop::collection::vec(0usize..150, 0..20),
        query in (0usize..6, 0usize..2, prop::option::of(0u64..40), 0u64..120, 0u64..3, 0u64..40),
        scope in scope_strategy(ROBOTS, SESSIONS),
        readable in prop::option::of(prop::collection::vec(robot_name(), 0..4)),
        history in prop::collection::vec((unit_vector(6), scene_strategy()), 1..4),
        k in 1usize..12,
        waiting in 0usize..8,
    ) {
        let mut with_graph = index_of(rows.clone(), Some(waiting));
        let mut without = index_of(rows.clone(), None);
        // Erasures move rows: the graph's keys must follow them.
        for r in removed {
            if let Some((robot, session, _, id, _, _)) = rows.get(r) {
                let key = KeyframeKey {
                    robot_id: ROBOTS[*robot].into(),
                    session_id: SESSIONS[*session].into(),
                    keyframe_id: *id,
                };
                with_graph.remove(&key);
                without.remove(&key);
            }
        }
        let context = context_of(query, scope, readable);
        let history = features_of(history);
        let query = ScalQuery { history: history.iter().collect() };
        let filter = with_graph.eligibility(&context);
        let reference = scal_scan(
            &VprParams { top_k: k, ..VprParams::default() },
            &query,
            &without,
            &without.eligibility(&context),
        );
        // Always the graph's candidates: only eligible rows, each scored
        // as the full pass scores it.
        let approximate = VprParams {
            top_k: k,
            approximate_from: 0,
            approximate_min_share: 0.0,
            ..VprParams::default()
        };
        let found = scal_scan(&approximate, &query, &with_graph, &filter);
        for hit in &found.hits {
            prop_assert!(filter.test(hit.row), "row {} is not eligible", hit.row);
            let key = &with_graph.meta(hit.row).key;
            let same = reference
                .hits
                .iter()
                .find(|h| &without.meta(h.row).key == key);
            if let Some(same) = same {
                prop_assert_eq!(same.score.to_bits(), hit.score.to_bits());
            }
        }
        prop_assert!(found.hits.len() <= reference.hits.len());
        // A map's own graph where the query may see one map, else a full
        // pass: still only eligible rows, each scored as the full pass
        // scores it.
        let by_map = VprParams { approximate_min_share: 2.0, ..approximate.clone() };
        let found = scal_scan(&by_map, &query, &with_graph, &filter);
        for hit in &found.hits {
            prop_assert!(filter.test(hit.row), "row {} is not eligible", hit.row);
            let key = &with_graph.meta(hit.row).key;
            if let Some(same) = reference.hits.iter().find(|h| &without.meta(h.row).key == key) {
                prop_assert_eq!(same.score.to_bits(), hit.score.to_bits());
            }
        }
        if filter.group().is_none() {
            assert_same_bits(&found, &reference)?;
        }
        // A full pass: below the switch point, for an exact query, or with
        // `vpr.exact`.
        let below = VprParams { top_k: k, approximate_from: usize::MAX, ..VprParams::default() };
        assert_same_bits(&scal_scan(&below, &query, &with_graph, &filter), &reference)?;
        assert_same_bits(&scal_scan(&approximate, &query, &with_graph, &filter.clone().exact()), &reference)?;
        let exact = VprParams { exact: true, ..approximate.clone() };
        assert_same_bits(&scal_scan(&exact, &query, &with_graph, &filter), &reference)?;
        // Once the waiting rows are added, the graph holds every row.
        drop(filter);
        with_graph.flush_graph_inserts();
        prop_assert_eq!(with_graph.neighbour_graph().unwrap().len(), with_graph.len() - with_graph.neighbour_graph_missing());
        prop_assert_eq!(with_graph.neighbour_graph_waiting(), 0);
        let (_, map_rows, _) = with_graph.map_graphs();
        prop_assert_eq!(map_rows, with_graph.len() - with_graph.neighbour_graph_missing());
    }
}

#[test]
fn the_graphs_candidates_find_the_exact_best_match_of_a_revisited_place() {
    use crate::synthetic::{place_descriptor, Rng};
    let dim = 64;
    let mut noise = Rng::new(11);
    let mut index = Index::new(dim);
    index.keep_neighbour_graph(None).unwrap();
    // Four robots pass 500 places in runs of four keyframes, each robot
    // in its own map.
    for robot in 0..4 {
        for id in 0..1_500u64 {
            let place = crate::synthetic::place_of(500, robot as u64, id);
            let features = Features {
                descriptor: place_descriptor(dim, place, &mut noise),
                ..Features::default()
            };
            index.upsert(keyframe(robot, 0, 0, id, features));
        }
    }
    let exact = VprParams::default();
    let approximate = VprParams {
        approximate_from: 0,
        approximate_min_share: 0.0,
        ..VprParams::default()
    };
    let mut same = 0;
    let queries = 200;
    let (mut shifts, mut margins) = (Vec::new(), Vec::new());
    for q in 0..queries {
        let history = [Features {
            descriptor: place_descriptor(dim, q * 7 % 500, &mut noise),
            ..Features::default()
        }];
        let query = ScalQuery {
            history: history.iter().collect(),
        };
        let context = QueryContext {
            session: SessionKey {
                robot_id: ROBOTS[(q % 4) as usize].into(),
                session_id: SESSIONS[0].into(),
            },
            keyframe_id: None,
            frame_id: 0,
            map_id: 0,
            min_frame_gap: 0,
            scope: Scope::OtherMaps,
            readable_robots: None,
        };
        let filter = index.eligibility(&context);
        let a = scal_scan(&approximate, &query, &index, &filter);
        let e = scal_scan(&exact, &query, &index, &filter);
        assert_eq!(a.eligible, 4_500);
        assert!(a.hits.iter().all(|h| filter.test(h.row)));
        if a.hits.first().map(|h| h.row) == e.hits.first().map(|h| h.row) {
            same += 1;
        }
        shifts.push((a.null.location - e.null.location).abs());
        margins.push(e.hits[0].score - e.null.location);
    }
    assert!(same >= queries * 97 / 100, "{same} of {queries}");
    // The approximate null (a smaller tag sample, scored from the codes)
    // stays close to the exact one: against what the best candidate
    // stands above it, a shift of a few per cent.
    shifts.sort_by(f32::total_cmp);
    margins.sort_by(f32::total_cmp);
    let (shift, worst, margin) = (
        shifts[shifts.len() / 2],
        shifts[shifts.len() - 1],
        margins[margins.len() / 2],
    );
    eprintln!("null shift median {shift} worst {worst}; top-1 margin median {margin}");
    assert!(
        shift < 0.05 * margin,
        "median shift {shift} of margin {margin}"
    );
    assert!(
        worst < 0.15 * margin,
        "worst shift {worst} of margin {margin}"
    );
}

#[test]
fn a_deferred_batch_enters_the_graph_with_its_erasures_and_replacements() {
    use crate::synthetic::{place_descriptor, Rng};
    let dim = 32;
    let mut noise = Rng::new(5);
    let mut index = Index::new(dim);
    index.keep_neighbour_graph(None).unwrap();
    let stored = |id: u64, noise: &mut Rng| {
        let features = Features {
            descriptor: place_descriptor(dim, id, noise),
            ..Features::default()
        };
        keyframe((id % 3) as usize, 0, 0, id, features)
    };
    for id in 0..290 {
        index.upsert(stored(id, &mut noise));
    }
    index.defer_graph_inserts();
    for id in 290..300 {
        index.upsert(stored(id, &mut noise));
    }
    assert_eq!(index.neighbour_graph_waiting(), 10);
    // Erased while waiting, replaced while waiting, erased after entering.
    let key = |id: u64| KeyframeKey {
        robot_id: ROBOTS[(id % 3) as usize].into(),
        session_id: SESSIONS[0].into(),
        keyframe_id: id,
    };
    for id in [292, 270, 10] {
        index.remove(&key(id));
    }
    let replacement = stored(80, &mut noise);
    let replaced_descriptor = replacement.features.descriptor.clone();
    index.upsert(replacement);
    // Waiting rows are proposed, once each, after the graph's own.
    let row_80 = index.row_of(&key(80)).unwrap();
    let row_290 = index.row_of(&key(290)).unwrap();
    let proposed = index
        .nearest_rows(&replaced_descriptor, 1, &|_| true)
        .unwrap();
    // The graph's one, then 9 waiting and 80 (unless the graph's was 80).
    assert!((10..=11).contains(&proposed.len()), "{proposed:?}");
    assert!(proposed.contains(&row_80) && proposed.contains(&row_290));
    let mut unique = proposed.clone();
    unique.sort_unstable();
    unique.dedup();
    assert_eq!(unique.len(), proposed.len());
    // The filter applies to waiting rows too.
    let proposed = index
        .nearest_rows(&replaced_descriptor, 1, &|row| row != row_290)
        .unwrap();
    assert!(!proposed.contains(&row_290));
    // Added in two batches under a shared borrow, crossed off after each.
    let first = index.add_waiting_to_graph(5);
    assert_eq!(first.taken(), 5);
    index.graph_added(first);
    assert_eq!(index.neighbour_graph_waiting(), 6);
    index.flush_graph_inserts();
    assert_eq!(index.neighbour_graph_waiting(), 0);
    assert_eq!(index.neighbour_graph().unwrap().len(), 297);
    assert_eq!(index.neighbour_graph_missing(), 0);
    assert_eq!(
        index
            .nearest_rows(&replaced_descriptor, 1, &|_| true)
            .unwrap(),
        vec![row_80]
    );
    // The graph is built in parallel, so its walk may miss a row now and
    // then: nearly every stored row finds itself.
    let found = (0..index.len())
        .filter(|&row| {
            let descriptor = index.descriptor(row).to_vec();
            index.nearest_rows(&descriptor, 1, &|_| true).unwrap() == vec![row]
        })
        .count();
    assert!(
        found >= index.len() * 97 / 100,
        "{found} of {}",
        index.len()
    );
}

#[test]
fn a_graph_mostly_waiting_leaves_queries_to_a_full_pass() {
    use crate::synthetic::{place_descriptor, Rng};
    let dim = 16;
    let mut noise = Rng::new(9);
    let mut index = Index::new(dim);
    index.defer_graph_inserts();
    index.keep_neighbour_graph(None).unwrap();
    for id in 0..200 {
        let features = Features {
            descriptor: place_descriptor(dim, id, &mut noise),
            ..Features::default()
        };
        index.upsert(keyframe((id % 3) as usize, 0, 0, id, features));
    }
    // Every row waits: the graph is not asked.
    assert_eq!(index.neighbour_graph_waiting(), 200);
    let query = index.descriptor(7).to_vec();
    assert!(index.nearest_rows(&query, 5, &|_| true).is_none());
    index.flush_graph_inserts();
    // Once flushed, the graph answers. It is built in parallel, so its
    // walk may miss a row now and then: the row is among the nearest few.
    let nearest = index.nearest_rows(&query, 5, &|_| true).unwrap();
    assert!(nearest.contains(&7), "{nearest:?}");
}

/// A loop query of `ROBOTS[robot]` over its map 0 of session 0.
fn loop_query(robot: usize) -> QueryContext {
    QueryContext {
        session: SessionKey {
            robot_id: ROBOTS[robot].into(),
            session_id: SESSIONS[0].into(),
        },
        keyframe_id: None,
        frame_id: 0,
        map_id: 0,
        min_frame_gap: 0,
        scope: Scope::SameMap,
        readable_robots: None,
    }
}

#[test]
fn a_loop_query_over_a_large_map_walks_that_maps_own_graph() {
    use crate::synthetic::{place_descriptor, place_of, Rng};
    let dim = 64;
    let mut noise = Rng::new(12);
    let mut index = Index::new(dim);
    index.keep_neighbour_graph(None).unwrap();
    index.keep_map_graphs(1_000);
    // Four robots pass 500 places in runs of four keyframes, each in its
    // own map; robot 3's map stays under the size that gets a graph.
    for robot in 0..4 {
        let stored = if robot == 3 { 600 } else { 1_500u64 };
        for id in 0..stored {
            let features = Features {
                descriptor: place_descriptor(dim, place_of(500, robot as u64, id), &mut noise),
                ..Features::default()
            };
            index.upsert(keyframe(robot, 0, 0, id, features));
        }
    }
    assert_eq!(index.map_graphs().0, 3);
    assert_eq!(index.map_graphs().1, 4_500);
    // The store's graph only for a large share: a map (a quarter of the
    // store) takes its own.
    let by_map = VprParams {
        approximate_from: 1_000,
        approximate_min_share: 0.5,
        ..VprParams::default()
    };
    let context = loop_query;
    let (mut same, queries) = (0, 150);
    for q in 0..queries {
        let robot = (q % 3) as usize;
        let history = [Features {
            descriptor: place_descriptor(dim, q * 7 % 500, &mut noise),
            ..Features::default()
        }];
        let query = ScalQuery {
            history: history.iter().collect(),
        };
        let filter = index.eligibility(&context(robot));
        assert!(filter.group().is_some());
        let group = filter.group().unwrap();
        let proposed = index
            .nearest_rows_of_map(&history[0].descriptor, 100, group, &|r| filter.test(r))
            .expect("the map keeps a graph");
        assert!(proposed
            .iter()
            .all(|&r| index.meta(r).key.robot_id == ROBOTS[robot]));
        let a = scal_scan(&by_map, &query, &index, &filter);
        let e = scal_scan(&VprParams::default(), &query, &index, &filter);
        assert_eq!(a.eligible, 1_500);
        assert!(a.hits.iter().all(|h| filter.test(h.row)));
        same += usize::from(a.hits.first().map(|h| h.row) == e.hits.first().map(|h| h.row));
    }
    assert!(same >= queries as usize * 97 / 100, "{same} of {queries}");
    // The small map has no graph of its own: its loop query is the exact
    // pass, bit for bit.
    let filter = index.eligibility(&context(3));
    let group = filter.group().unwrap();
    assert!(index
        .nearest_rows_of_map(&[0.0; 64], 10, group, &|_| true)
        .is_none());
    let history = [Features {
        descriptor: place_descriptor(dim, 3, &mut noise),
        ..Features::default()
    }];
    let query = ScalQuery {
        history: history.iter().collect(),
    };
    let a = scal_scan(&by_map, &query, &index, &filter);
    let e = scal_scan(&VprParams::default(), &query, &index, &filter);
    assert_eq!(
        a.hits
            .iter()
            .map(|h| (h.row, h.score.to_bits()))
            .collect::<Vec<_>>(),
        e.hits
            .iter()
            .map(|h| (h.row, h.score.to_bits()))
            .collect::<Vec<_>>()
    );
}

#[test]
fn a_maps_graph_starts_when_the_map_grows_large_and_follows_its_keyframes() {
    let mut index = Index::new(6);
    index.keep_neighbour_graph(None).unwrap();
    index.keep_map_graphs(20);
    index.defer_graph_inserts();
    let mut noise = crate::synthetic::Rng::new(5);
    let mut store = |index: &mut Index, robot: usize, map: u64, id: u64| {
        let descriptor = crate::synthetic::place_descriptor(6, id, &mut noise);
        index.upsert(keyframe(
            robot,
            0,
            map,
            id,
            Features {
                descriptor,
                ..Features::default()
            },
        ));
    };
    for id in 0..19 {
        store(&mut index, 0, 0, id);
    }
    assert_eq!(index.map_graphs().0, 0);
    // The twentieth keyframe starts the map's graph, every row waiting.
    store(&mut index, 0, 0, 19);
    assert_eq!(index.map_graphs(), (1, 0, index.map_graphs().2));
    assert_eq!(index.neighbour_graph_waiting(), 20 + 20);
    let group = index.eligibility(&loop_query(0)).group().unwrap();
    // Mostly waiting: the exact pass.
    assert!(index
        .nearest_rows_of_map(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 1, group, &|_| true)
        .is_none());
    index.flush_graph_inserts();
    assert_eq!(index.map_graphs().1, 20);
    assert_eq!(index.neighbour_graph_waiting(), 0);
    // Another robot's keyframes never enter it.
    for id in 0..5 {
        store(&mut index, 1, 0, id);
    }
    index.flush_graph_inserts();
    assert_eq!(index.map_graphs().1, 20);
    // A keyframe erased leaves it; one stored again in another map (a
    // merge renumbers maps) moves to that map, which has no graph.
    let key = |id: u64| KeyframeKey {
        robot_id: ROBOTS[0].into(),
        session_id: SESSIONS[0].into(),
        keyframe_id: id,
    };
    index.remove(&key(3));
    store(&mut index, 0, 1, 4);
    index.flush_graph_inserts();
    assert_eq!(index.map_graphs().1, 18);
    let everything = index
        .nearest_rows_of_map(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 100, group, &|_| true)
        .unwrap();
    assert_eq!(everything.len(), 18);
    assert!(everything
        .iter()
        .all(|&r| index.meta(r).map_id == 0 && index.meta(r).key.robot_id == ROBOTS[0]));
}
