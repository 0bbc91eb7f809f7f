//! SLAM's geometric verdicts on the candidates HuMem proposed, as plain
//! data, and the book that holds them in memory beside the index.
//!
//! A verdict names two stored keyframes (the query and the candidate), the
//! check that ran (loop, merge, relocalisation) and its outcome. It lives
//! exactly as long as both keyframes do: [`VerdictBook::forget`] drops every
//! verdict that names a keyframe being removed, so erasures and resets
//! carry them away (the store does the same on disk in the same
//! transaction). The newest verdict on a (query, candidate, kind) triple
//! replaces an older one. What the verdicts do to a ranking is
//! [`crate::vpr::feedback`]'s business, not this module's.

use std::collections::{HashMap, HashSet};

use serde::{Deserialize, Serialize};

use crate::keyframe::{KeyframeKey, Pose, SessionKey};

/// Which geometric check the SLAM system ran on a candidate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum VerificationKind {
    /// Loop closure within one map (Sim3 and the coincidence check).
    Loop,
    /// A merge of two maps of the atlas.
    Merge,
    /// Relocalisation of a lost frame (PnP).
    Relocalisation,
}

impl VerificationKind {
    /// One byte, for store keys.
    pub fn tag(self) -> u8 {
        match self {
            VerificationKind::Loop => 1,
            VerificationKind::Merge => 2,
            VerificationKind::Relocalisation => 3,
        }
    }
}

/// A similarity transform estimated by the geometric check.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RelativeTransform {
    /// `T_qc`: the candidate camera in the query camera's frame.
    pub pose: Pose,
    /// Scale of a Sim(3) estimate; 1 for SE(3).
    pub scale: f64,
}

/// One verdict, as stored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    /// The query keyframe the candidate was proposed for.
    pub query: KeyframeKey,
    /// The candidate keyframe that was checked.
    pub candidate: KeyframeKey,
    /// Which check ran.
    pub kind: VerificationKind,
    /// Whether the check verified the candidate.
    pub accepted: bool,
    /// The transform the check estimated, when accepted.
    pub relative: Option<RelativeTransform>,
    /// The score HuMem gave the candidate when it proposed it, if the
    /// client said.
    pub score: Option<f32>,
    /// Inliers of the check (0: not said).
    pub inliers: u32,
    /// When the server received it, in seconds since the Unix epoch; the
    /// verdict's weight decays from here (`vpr.verdicts.half_life_hours`).
    pub reported_at: f64,
}

/// Seconds since the Unix epoch: the clock verdicts are stamped and decay
/// by.
pub fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// What identifies a verdict: the newest one for the same triple wins.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct VerdictKey {
    /// The query keyframe.
    pub query: KeyframeKey,
    /// The candidate keyframe.
    pub candidate: KeyframeKey,
    /// The check.
    pub kind: VerificationKind,
}

impl Verdict {
    /// Its identity.
    pub fn key(&self) -> VerdictKey {
        VerdictKey {
            query: self.query.clone(),
            candidate: self.candidate.clone(),
            kind: self.kind,
        }
    }
}

/// The verdicts in memory, with the lookups ranking and erasure need.
#[derive(Debug, Default, Clone)]
pub struct VerdictBook {
    verdicts: HashMap<VerdictKey, Verdict>,
    /// Verdicts naming each keyframe, as query or candidate.
    by_keyframe: HashMap<KeyframeKey, HashSet<VerdictKey>>,
    /// Verdicts naming a keyframe of each session.
    by_session: HashMap<SessionKey, HashSet<VerdictKey>>,
}

impl VerdictBook {
    /// An empty book.
    pub fn new() -> Self {
        Self::default()
    }

    /// Verdicts held.
    pub fn len(&self) -> usize {
        self.verdicts.len()
    }

    /// Whether it holds none.
    pub fn is_empty(&self) -> bool {
        self.verdicts.is_empty()
    }

    /// Adds a verdict, replacing one on the same triple; says whether one
    /// was replaced.
    pub fn record(&mut self, verdict: Verdict) -> bool {
        let key = verdict.key();
        for keyframe in [&verdict.query, &verdict.candidate] {
            self.by_keyframe
                .entry(keyframe.clone())
                .or_default()
                .insert(key.clone());
            self.by_session
                .entry(keyframe.session())
                .or_default()
                .insert(key.clone());
        }
        self.verdicts.insert(key, verdict).is_some()
    }

    /// Drops every verdict that names `keyframe`; returns how many.
    pub fn forget(&mut self, keyframe: &KeyframeKey) -> usize {
        let Some(keys) = self.by_keyframe.remove(keyframe) else {
            return 0;
        };
        let mut dropped = 0;
        for key in keys {
            let Some(verdict) = self.verdicts.remove(&key) else {
                continue;
            };
            dropped += 1;
            for other in [&verdict.query, &verdict.candidate] {
                if let Some(set) = self.by_keyframe.get_mut(other) {
                    set.remove(&key);
                    if set.is_empty() {
                        self.by_keyframe.remove(other);
                    }
                }
                let session = other.session();
                if let Some(set) = self.by_session.get_mut(&session) {
                    set.remove(&key);
                    if set.is_empty() {
                        self.by_session.remove(&session);
                    }
                }
            }
        }
        dropped
    }

    /// Every verdict, in no particular order.
    pub fn iter(&self) -> impl Iterator<Item = &Verdict> {
        self.verdicts.values()
    }

    /// The verdicts naming any of `keyframes`, each once.
    pub fn naming<'a, 'k>(
        &'a self,
        keyframes: impl IntoIterator<Item = &'k KeyframeKey>,
    ) -> Vec<&'a Verdict> {
        self.each_once(keyframes.into_iter().map(|k| self.by_keyframe.get(k)))
    }

    /// The verdicts naming a keyframe of any of `sessions`, each once.
    pub fn touching<'a, 's>(
        &'a self,
        sessions: impl IntoIterator<Item = &'s SessionKey>,
    ) -> Vec<&'a Verdict> {
        self.each_once(sessions.into_iter().map(|s| self.by_session.get(s)))
    }

    /// The verdicts of the key sets of a lookup table, each once.
    fn each_once<'a>(
        &'a self,
        sets: impl Iterator<Item = Option<&'a HashSet<VerdictKey>>>,
    ) -> Vec<&'a Verdict> {
        let mut seen = HashSet::new();
        sets.flatten()
            .flatten()
            .filter(|key| seen.insert(*key))
            .filter_map(|key| self.verdicts.get(key))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kf(robot: &str, id: u64) -> KeyframeKey {
        KeyframeKey {
            robot_id: robot.into(),
            session_id: "s".into(),
            keyframe_id: id,
        }
    }

    fn verdict(q: KeyframeKey, c: KeyframeKey, accepted: bool) -> Verdict {
        Verdict {
            query: q,
            candidate: c,
            kind: VerificationKind::Loop,
            accepted,
            relative: None,
            score: None,
            inliers: 0,
            reported_at: 0.0,
        }
    }

    #[test]
    fn newest_verdict_on_a_pair_wins_and_erasure_follows_both_ends() {
        let mut book = VerdictBook::new();
        assert!(!book.record(verdict(kf("a", 10), kf("a", 1), false)));
        assert!(book.record(verdict(kf("a", 10), kf("a", 1), true)));
        assert_eq!(book.len(), 1);
        assert!(book.iter().next().unwrap().accepted);
        book.record(verdict(kf("a", 11), kf("b", 2), false));
        book.record(verdict(kf("a", 12), kf("a", 1), false));
        assert_eq!(book.len(), 3);
        // The candidate end: both verdicts on a/1 go.
        assert_eq!(book.forget(&kf("a", 1)), 2);
        assert_eq!(book.len(), 1);
        let b = SessionKey {
            robot_id: "b".into(),
            session_id: "s".into(),
        };
        assert_eq!(book.touching([&b]).len(), 1);
        // The query end.
        assert_eq!(book.forget(&kf("a", 11)), 1);
        assert!(book.is_empty());
        assert!(book.touching([&b]).is_empty());
        assert_eq!(book.forget(&kf("a", 11)), 0);
    }
}
