//! Interned robot and session ids, and the eligibility rule compiled
//! against them for the scan.
//!
//! The scan tests eligibility on every stored row. Comparing the strings of
//! each row's key costs two pointer chases and a `memcmp` per row, more
//! than the row's code dot products. So the index keeps, row-aligned, a
//! small table of integers ([`RowIds`]), and a query's [`QueryContext`] is
//! compiled once into integer comparisons ([`Eligibility`]). The rule is the
//! one in [`vpr::eligibility`](crate::vpr::eligibility); a property test
//! checks that both agree on every row.

use std::collections::HashMap;

use crate::vpr::eligibility::{QueryContext, Scope};

/// The integers the eligibility rule reads about one stored keyframe.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RowIds {
    /// Interned robot id.
    pub robot: u32,
    /// Interned (robot, session) pair.
    pub session: u32,
    /// Atlas map id within the session.
    pub map_id: u64,
    /// Source-frame id.
    pub frame_id: u64,
    /// Keyframe id within the session.
    pub keyframe_id: u64,
}

/// Robot and session strings to dense integers. Ids are never reused or
/// released: a fleet has few robots and sessions next to its keyframes.
/// Lookups borrow the strings, so interning a known session (every insert)
/// allocates nothing.
#[derive(Debug, Clone, Default)]
pub struct Interner {
    robots: HashMap<String, RobotIds>,
    sessions: u32,
}

/// One robot's id and the ids of its sessions.
#[derive(Debug, Clone)]
struct RobotIds {
    id: u32,
    sessions: HashMap<String, u32>,
}

impl Interner {
    /// The ids of a robot and one of its sessions, interning them if new.
    pub fn intern(&mut self, robot_id: &str, session_id: &str) -> (u32, u32) {
        if !self.robots.contains_key(robot_id) {
            let id = self.robots.len() as u32;
            self.robots.insert(
                robot_id.to_string(),
                RobotIds {
                    id,
                    sessions: HashMap::new(),
                },
            );
        }
        let robot = self.robots.get_mut(robot_id).expect("interned above");
        let id = match robot.sessions.get(session_id) {
            Some(&id) => id,
            None => {
                let id = self.sessions;
                self.sessions += 1;
                robot.sessions.insert(session_id.to_string(), id);
                id
            }
        };
        (robot.id, id)
    }

    fn robot(&self, robot_id: &str) -> Option<u32> {
        self.robots.get(robot_id).map(|r| r.id)
    }

    fn session(&self, robot_id: &str, session_id: &str) -> Option<u32> {
        self.robots.get(robot_id)?.sessions.get(session_id).copied()
    }
}

/// A map named in a listed scope, compiled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct MapIds {
    robot: u32,
    /// `None`: any session of the robot.
    session: Option<u32>,
    map_id: u64,
}

/// The compiled scope.
#[derive(Debug, Clone, PartialEq, Eq)]
enum CompiledScope {
    SameMap,
    OtherMaps,
    AllMaps,
    Listed { robots: Vec<u32>, maps: Vec<MapIds> },
}

/// A query's eligibility rule over a table of [`RowIds`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Eligibility {
    /// The query's session, if any stored keyframe has it (else no row is
    /// in the query's session).
    session: Option<u32>,
    keyframe_id: Option<u64>,
    frame_id: u64,
    map_id: u64,
    min_frame_gap: u64,
    scope: CompiledScope,
    /// Interned robots the caller may read; `None`: every robot.
    readable: Option<Vec<u32>>,
}

impl Eligibility {
    /// Compiles `context` against the ids interned so far. Names that were
    /// never interned match no row.
    pub fn compile(context: &QueryContext, interner: &Interner) -> Eligibility {
        let session = interner.session(&context.session.robot_id, &context.session.session_id);
        let scope = match &context.scope {
            Scope::SameMap => CompiledScope::SameMap,
            Scope::OtherMaps => CompiledScope::OtherMaps,
            Scope::AllMaps => CompiledScope::AllMaps,
            Scope::Listed { robot_ids, maps } => CompiledScope::Listed {
                robots: robot_ids.iter().filter_map(|r| interner.robot(r)).collect(),
                maps: maps
                    .iter()
                    .filter_map(|m| {
                        let robot = interner.robot(&m.robot_id)?;
                        let session = match &m.session_id {
                            None => None,
                            Some(s) => Some(interner.session(&m.robot_id, s)?),
                        };
                        Some(MapIds {
                            robot,
                            session,
                            map_id: m.map_id,
                        })
                    })
                    .collect(),
            },
        };
        Eligibility {
            session,
            keyframe_id: context.keyframe_id,
            frame_id: context.frame_id,
            map_id: context.map_id,
            min_frame_gap: context.min_frame_gap,
            scope,
            readable: context
                .readable_robots
                .as_ref()
                .map(|robots| robots.iter().filter_map(|r| interner.robot(r)).collect()),
        }
    }

    /// Whether a row with `ids` may be proposed.
    #[inline]
    pub fn test(&self, ids: &RowIds) -> bool {
        let own_session = self.session == Some(ids.session);
        let gap = !own_session
            || (self.keyframe_id != Some(ids.keyframe_id)
                && self.frame_id.abs_diff(ids.frame_id) >= self.min_frame_gap);
        gap && self.admits_map(ids.robot, ids.session, ids.map_id)
    }

    /// Whether the keyframes of one map (robot, session, map id) may be
    /// proposed as far as the scope and read access go: false means no row
    /// of the map passes [`Eligibility::test`], true that the gap rule
    /// decides row by row. What a scan restricted to the allowed maps
    /// relies on.
    #[inline]
    pub fn admits_map(&self, robot: u32, session: u32, map_id: u64) -> bool {
        if self
            .readable
            .as_ref()
            .is_some_and(|robots| !robots.contains(&robot))
        {
            return false;
        }
        let same_map = self.session == Some(session) && map_id == self.map_id;
        match &self.scope {
            CompiledScope::SameMap => same_map,
            CompiledScope::OtherMaps => !same_map,
            CompiledScope::AllMaps => true,
            CompiledScope::Listed { robots, maps } => {
                robots.contains(&robot)
                    || maps.iter().any(|m| {
                        m.robot == robot
                            && m.map_id == map_id
                            && m.session.is_none_or(|s| s == session)
                    })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::keyframe::{KeyframeKey, SessionKey};
    use crate::vpr::eligibility::{is_eligible, CandidateMeta};
    use crate::vpr::testing::scope_strategy;
    use proptest::prelude::*;

    const NAMES: &[&str] = &["a", "b", "c"];

    fn name() -> impl Strategy<Value = String> {
        prop::sample::select(NAMES).prop_map(str::to_string)
    }

    fn scope() -> impl Strategy<Value = Scope> {
        scope_strategy(NAMES, NAMES)
    }

    proptest! {
        #[test]
        fn compiled_rule_agrees_with_the_string_rule(
            rows in prop::collection::vec((name(), name(), 0u64..6, 0u64..3, 0u64..400), 1..40),
            query in (name(), name(), prop::option::of(0u64..6), 0u64..400, 0u64..3, 0u64..200),
            scope in scope(),
            readable in prop::option::of(prop::collection::vec(name(), 0..3)),
        ) {
            let mut interner = Interner::default();
            let keys: Vec<(KeyframeKey, u64, u64, RowIds)> = rows
                .into_iter()
                // Leave robot "c" out of the store: names never interned.
                .filter(|(robot, ..)| robot != "c")
                .map(|(robot_id, session_id, keyframe_id, map_id, frame_id)| {
                    let key = KeyframeKey { robot_id, session_id, keyframe_id };
                    let (robot, session) = interner.intern(&key.robot_id, &key.session_id);
                    let ids = RowIds { robot, session, map_id, frame_id, keyframe_id };
                    (key, frame_id, map_id, ids)
                })
                .collect();
            let (robot_id, session_id, keyframe_id, frame_id, map_id, min_frame_gap) = query;
            let context = QueryContext {
                session: SessionKey { robot_id, session_id },
                keyframe_id,
                frame_id,
                map_id,
                min_frame_gap,
                scope,
                readable_robots: readable,
            };
            let rule = Eligibility::compile(&context, &interner);
            for (key, frame_id, map_id, ids) in &keys {
                let expected = is_eligible(
                    &context,
                    &CandidateMeta { key, frame_id: *frame_id, map_id: *map_id },
                );
                prop_assert_eq!(rule.test(ids), expected, "{:?}", key);
                // A row that passes is in a map the rule admits: a scan of
                // the admitted maps' rows misses none.
                prop_assert!(!expected || rule.admits_map(ids.robot, ids.session, ids.map_id));
            }
        }
    }
}
