//! Which stored keyframes may be proposed for a query.
//!
//! Two independent rules, both of which must pass: the temporal gap (a
//! keyframe of the query's own robot and session must be at least
//! `min_frame_gap` source frames away, and never the query keyframe itself;
//! other robots and sessions are always far enough) and the scope (which maps
//! the caller asks about: its own map for loop closure, other maps for map
//! merging, or an explicit list). A map is identified by the triple
//! (robot, session, map id) because atlas map ids restart per session.
//!
//! On top of both, the caller's read access (`readable_robots`, from the
//! server's access rules) narrows any scope to the robots it may read.

use crate::keyframe::{KeyframeKey, SessionKey};

/// One map, or every map of a robot's session when `session_id` is `None`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MapRef {
    /// The robot that made the map.
    pub robot_id: String,
    /// `None` matches any session of the robot.
    pub session_id: Option<String>,
    /// Atlas map id within the session.
    pub map_id: u64,
}

/// Which maps the candidates may come from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Scope {
    /// Only the query's own map (loop closure, relocalisation).
    SameMap,
    /// Any map other than the query's (map merging).
    OtherMaps,
    /// Everything in the store.
    AllMaps,
    /// Candidates whose robot is listed, or whose map matches a [`MapRef`].
    Listed {
        /// Robots all of whose keyframes may be proposed.
        robot_ids: Vec<String>,
        /// Maps whose keyframes may be proposed.
        maps: Vec<MapRef>,
    },
}

/// What the eligibility rule needs to know about the query.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct QueryContext {
    /// The query's robot and session.
    pub session: SessionKey,
    /// The query's own keyframe id, if it is (or will be) stored.
    pub keyframe_id: Option<u64>,
    /// Source-frame id `f_t`.
    pub frame_id: u64,
    /// Atlas map id of the query within its session.
    pub map_id: u64,
    /// Minimum `|f_t − f_i|` within the same robot and session (paper: 100).
    pub min_frame_gap: u64,
    /// Which maps the candidates may come from.
    pub scope: Scope,
    /// The robots whose keyframes the caller may read; `None`: every robot.
    pub readable_robots: Option<Vec<String>>,
}

/// Candidate metadata needed for the rule.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CandidateMeta<'a> {
    /// Identity of the stored keyframe.
    pub key: &'a KeyframeKey,
    /// Source-frame id `f_i`.
    pub frame_id: u64,
    /// Atlas map id of the candidate within its session.
    pub map_id: u64,
}

/// Gap rule, scope rule and read access together.
pub fn is_eligible(query: &QueryContext, cand: &CandidateMeta) -> bool {
    passes_gap(query, cand) && in_scope(query, cand) && readable(query, cand)
}

fn readable(query: &QueryContext, cand: &CandidateMeta) -> bool {
    query
        .readable_robots
        .as_ref()
        .is_none_or(|robots| robots.contains(&cand.key.robot_id))
}

/// Same robot and session: `|f_t − f_i| ≥ min_frame_gap` and not the query
/// keyframe itself. Other robots or sessions: always.
fn passes_gap(query: &QueryContext, cand: &CandidateMeta) -> bool {
    if !cand.key.in_session(&query.session) {
        return true;
    }
    if query.keyframe_id == Some(cand.key.keyframe_id) {
        return false;
    }
    query.frame_id.abs_diff(cand.frame_id) >= query.min_frame_gap
}

fn in_scope(query: &QueryContext, cand: &CandidateMeta) -> bool {
    let same_map = cand.key.in_session(&query.session) && cand.map_id == query.map_id;
    match &query.scope {
        Scope::SameMap => same_map,
        Scope::OtherMaps => !same_map,
        Scope::AllMaps => true,
        Scope::Listed { robot_ids, maps } => {
            robot_ids.contains(&cand.key.robot_id) || maps.iter().any(|m| map_matches(m, cand))
        }
    }
}

fn map_matches(map: &MapRef, cand: &CandidateMeta) -> bool {
    map.robot_id == cand.key.robot_id
        && map.map_id == cand.map_id
        && map
            .session_id
            .as_ref()
            .is_none_or(|s| *s == cand.key.session_id)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(robot: &str, session: &str, id: u64) -> KeyframeKey {
        KeyframeKey {
            robot_id: robot.into(),
            session_id: session.into(),
            keyframe_id: id,
        }
    }

    /// Query: robot r1, session s1, keyframe 7, frame 1000, map 0, gap 100.
    fn query(scope: Scope) -> QueryContext {
        QueryContext {
            session: SessionKey {
                robot_id: "r1".into(),
                session_id: "s1".into(),
            },
            keyframe_id: Some(7),
            frame_id: 1000,
            map_id: 0,
            min_frame_gap: 100,
            scope,
            readable_robots: None,
        }
    }

    fn eligible(q: &QueryContext, k: &KeyframeKey, frame_id: u64, map_id: u64) -> bool {
        is_eligible(
            q,
            &CandidateMeta {
                key: k,
                frame_id,
                map_id,
            },
        )
    }

    #[test]
    fn same_session_needs_the_frame_gap() {
        let q = query(Scope::AllMaps);
        let k = key("r1", "s1", 3);
        // |1000 − 901| = 99 < 100; |1000 − 900| = 100 ≥ 100.
        assert!(!eligible(&q, &k, 901, 0));
        assert!(eligible(&q, &k, 900, 0));
        // The gap is symmetric: a later frame counts too.
        assert!(!eligible(&q, &k, 1099, 0));
        assert!(eligible(&q, &k, 1100, 0));
    }

    #[test]
    fn other_robot_or_session_is_eligible_with_zero_gap() {
        let q = query(Scope::AllMaps);
        assert!(eligible(&q, &key("r2", "s1", 7), 1000, 0));
        assert!(eligible(&q, &key("r1", "s2", 7), 1000, 0));
    }

    #[test]
    fn the_query_keyframe_itself_is_excluded() {
        let mut q = query(Scope::AllMaps);
        q.min_frame_gap = 0;
        assert!(!eligible(&q, &key("r1", "s1", 7), 1000, 0));
        assert!(eligible(&q, &key("r1", "s1", 8), 1000, 0));
        q.keyframe_id = None;
        assert!(eligible(&q, &key("r1", "s1", 7), 1000, 0));
    }

    #[test]
    fn same_map_scope() {
        let q = query(Scope::SameMap);
        assert!(eligible(&q, &key("r1", "s1", 1), 0, 0));
        assert!(!eligible(&q, &key("r1", "s1", 1), 0, 1));
        // Same map id in another session or robot is another map.
        assert!(!eligible(&q, &key("r1", "s2", 1), 0, 0));
        assert!(!eligible(&q, &key("r2", "s1", 1), 0, 0));
    }

    #[test]
    fn other_maps_scope() {
        let q = query(Scope::OtherMaps);
        assert!(!eligible(&q, &key("r1", "s1", 1), 0, 0));
        assert!(eligible(&q, &key("r1", "s1", 1), 0, 1));
        assert!(eligible(&q, &key("r1", "s2", 1), 0, 0));
        assert!(eligible(&q, &key("r2", "s1", 1), 0, 0));
    }

    #[test]
    fn all_maps_scope_still_applies_the_gap() {
        let q = query(Scope::AllMaps);
        assert!(eligible(&q, &key("r3", "x", 1), 1000, 9));
        assert!(!eligible(&q, &key("r1", "s1", 1), 950, 0));
    }

    #[test]
    fn listed_scope() {
        let q = query(Scope::Listed {
            robot_ids: vec!["r2".into()],
            maps: vec![
                MapRef {
                    robot_id: "r3".into(),
                    session_id: None,
                    map_id: 4,
                },
                MapRef {
                    robot_id: "r1".into(),
                    session_id: Some("s1".into()),
                    map_id: 2,
                },
            ],
        });
        // Listed robot: any map.
        assert!(eligible(&q, &key("r2", "any", 1), 0, 17));
        // MapRef with session None: any session of r3, map 4 only.
        assert!(eligible(&q, &key("r3", "a", 1), 0, 4));
        assert!(eligible(&q, &key("r3", "b", 1), 0, 4));
        assert!(!eligible(&q, &key("r3", "a", 1), 0, 5));
        // MapRef with a session: only that session.
        assert!(eligible(&q, &key("r1", "s1", 1), 0, 2));
        assert!(!eligible(&q, &key("r1", "s9", 1), 0, 2));
        // Not listed at all.
        assert!(!eligible(&q, &key("r4", "s1", 1), 0, 4));
        // Listed, but the gap rule still applies within the query's session.
        assert!(!eligible(&q, &key("r1", "s1", 1), 950, 2));
    }

    #[test]
    fn read_access_narrows_every_scope() {
        for scope in [
            Scope::AllMaps,
            Scope::OtherMaps,
            Scope::Listed {
                robot_ids: vec!["r2".into(), "r3".into()],
                maps: vec![],
            },
        ] {
            let mut q = query(scope);
            q.readable_robots = Some(vec!["r1".into(), "r2".into()]);
            assert!(eligible(&q, &key("r2", "s", 1), 0, 9));
            assert!(!eligible(&q, &key("r3", "s", 1), 0, 9), "{:?}", q.scope);
            q.readable_robots = Some(vec![]);
            assert!(!eligible(&q, &key("r2", "s", 1), 0, 9));
        }
    }
}
