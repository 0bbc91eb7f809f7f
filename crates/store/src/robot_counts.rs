//! Keyframes held per robot, as the writer sees sled: what the keyframe
//! quota is checked against.
//!
//! The quota is checked where changes are applied one at a time, in the
//! writer, so no two inserts can both pass it on the same count (as they
//! could when each checked the index before queueing its change); in
//! cluster mode every replica applies the log in the same order and so
//! refuses the same inserts. Counting in the writer rather than asking the
//! index matters because the index lags the writer by the groups waiting
//! to be published.

use std::collections::HashMap;

use humem_core::index::Index;

/// Keyframes per robot id.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub(super) struct RobotCounts(HashMap<String, u64>);

/// Changes to the counts, per robot (negative: removed keyframes).
pub(super) type Deltas = HashMap<String, i64>;

impl RobotCounts {
    /// The counts of an index that equals the tree (as at open).
    pub fn of(index: &Index) -> Self {
        let mut counts = HashMap::new();
        for (map, keyframes) in index.map_counts() {
            *counts.entry(map.session.robot_id).or_default() += keyframes as u64;
        }
        RobotCounts(counts)
    }

    /// Keyframes `robot` holds.
    pub fn held(&self, robot: &str) -> u64 {
        self.0.get(robot).copied().unwrap_or(0)
    }

    /// Adds `deltas` (`sign` -1 takes them back).
    pub fn add(&mut self, deltas: &Deltas, sign: i64) {
        for (robot, delta) in deltas {
            let held = self.0.entry(robot.clone()).or_default();
            *held = held.saturating_add_signed(delta * sign);
            if *held == 0 {
                self.0.remove(robot);
            }
        }
    }
}

/// Adds `more` into `into`.
pub(super) fn merge(into: &mut Deltas, more: &Deltas) {
    for (robot, delta) in more {
        *into.entry(robot.clone()).or_default() += delta;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deltas_add_and_take_back() {
        let mut counts = RobotCounts::default();
        let deltas: Deltas = [("a".to_string(), 3), ("b".to_string(), 1)].into();
        counts.add(&deltas, 1);
        counts.add(&[("a".to_string(), -1)].into(), 1);
        assert_eq!(
            (counts.held("a"), counts.held("b"), counts.held("c")),
            (2, 1, 0)
        );
        counts.add(&deltas, -1);
        // a: 2 - 3 stops at 0; robots at 0 are forgotten.
        assert_eq!(counts, RobotCounts::default());
    }
}
