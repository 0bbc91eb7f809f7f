//! A query's eligibility rule bound to the index's rows, with the rows of
//! the maps it admits as the partition a scan visits when they are a
//! small part of the store.
//!
//! The partition is gathered (and sorted) only when a scan asks for it:
//! a loop query answered through its map's own graph never passes over
//! the map, and gathering a 30 000-keyframe map's rows for every such
//! query cost a fleet server a tenth of its time.

use std::collections::BTreeMap;
use std::sync::OnceLock;

use crate::engine::filter::{for_each_tagged, RowFilter, RowGroup};
use crate::row_ids::{Eligibility, RowIds};
use crate::vpr::eligibility::QueryContext;

use super::table::Index;

impl Index {
    /// The eligibility rule of `context`, compiled for this index's rows:
    /// `test(row)` agrees with [`is_eligible`](crate::vpr::eligibility::is_eligible) on the row's keyframe.
    /// It names the rows of the maps the rule admits as its partition, so
    /// that a scan visits only those, when they are at most
    /// [`PARTITION_MAX_SHARE`] of the store.
    pub fn eligibility(&self, context: &QueryContext) -> RowEligibility<'_> {
        let rule = Eligibility::compile(context, &self.interner);
        let (tracks, admitted, group) = self.admitted_tracks(&rule);
        RowEligibility {
            rule,
            ids: &self.ids,
            tracks,
            partition: OnceLock::new(),
            admitted: Some(admitted),
            group,
        }
    }

    /// The tracks of every map `rule` admits (scope and read access), or
    /// `None` when their rows are more than [`PARTITION_MAX_SHARE`] of the
    /// store; how many rows they hold; and the map's group where `rule`
    /// admits one map only. The tracks are the partition: every row is in
    /// its map's track, so counting costs one look per map.
    #[allow(clippy::type_complexity)]
    fn admitted_tracks(
        &self,
        rule: &Eligibility,
    ) -> (Option<Vec<AdmittedMap<'_>>>, usize, Option<RowGroup>) {
        let admitted: Vec<AdmittedMap<'_>> = self
            .tracks
            .iter()
            .filter(|(_, track)| {
                track.values().next().is_some_and(|&row| {
                    let ids = &self.ids[row];
                    rule.admits_map(ids.robot, ids.session, ids.map_id)
                })
            })
            .map(|(map, track)| AdmittedMap {
                track,
                sampled: self.sampled.get(map),
            })
            .collect();
        let count: usize = admitted.iter().map(|map| map.track.len()).sum();
        let group = match admitted.as_slice() {
            [map] => map.track.values().next().map(|&row| self.row_group(row)),
            _ => None,
        };
        if count as f64 > PARTITION_MAX_SHARE * self.len() as f64 {
            return (None, count, group);
        }
        (Some(admitted), count, group)
    }

    /// The group of `row`'s map, as [`RowFilter::group`] names it: its
    /// interned session (robot and session) and its map id.
    pub(super) fn row_group(&self, row: usize) -> RowGroup {
        let ids = &self.ids[row];
        (RowGroup::from(ids.session) << 64) | RowGroup::from(ids.map_id)
    }
}

/// The largest share of the store a query's admitted maps may hold for
/// its scan to visit only their rows ([`Index::eligibility`]). Past it a
/// scan of every row in order costs no more than gathering the rows
/// (`humem bench scan`, the scoped case).
pub const PARTITION_MAX_SHARE: f64 = 0.5;

/// The low bits of a sample tag that must be zero for its keyframe to be
/// kept in its map's sampled subset ([`Index`]'s `sampled`): one keyframe
/// in eight. A null sample whose mask covers these bits (a map of more
/// than 8 192 keyframes, [`NULL_SAMPLE_CAP`](crate::vpr::calibration::NULL_SAMPLE_CAP)
/// times 4) is drawn from the subset: walking a 30 000-keyframe map's
/// whole track for every loop query cost a fleet server a tenth of its
/// time.
pub const SAMPLED_MASK: u32 = 7;

/// One map a query's rule admits: its track, and its sampled subset.
#[derive(Debug, Clone, Copy)]
struct AdmittedMap<'a> {
    track: &'a BTreeMap<u64, usize>,
    sampled: Option<&'a BTreeMap<u64, u32>>,
}

/// A query's eligibility rule bound to an index's rows, with the rows it
/// can admit when they are a small part of the store.
#[derive(Debug, Clone)]
pub struct RowEligibility<'a> {
    rule: Eligibility,
    ids: &'a [RowIds],
    /// The admitted maps, where their tracks are the partition.
    tracks: Option<Vec<AdmittedMap<'a>>>,
    /// Their rows, sorted, gathered the first time a scan asks.
    partition: OnceLock<Vec<usize>>,
    /// Rows of the maps the rule admits; None once the query asked for an
    /// exact pass ([`RowEligibility::exact`]).
    admitted: Option<usize>,
    /// The one map the rule admits, where it admits one.
    group: Option<RowGroup>,
}

impl RowEligibility<'_> {
    /// Whether `row` may be proposed. Panics if `row` is out of range.
    #[inline]
    pub fn test(&self, row: usize) -> bool {
        self.rule.test(&self.ids[row])
    }

    /// The same rule, naming no partition: a scan with it visits every
    /// row (the reference the partitioned scan is checked against, and the
    /// baseline `humem bench scan` measures it with).
    pub fn without_partition(mut self) -> Self {
        self.tracks = None;
        self.partition = OnceLock::new();
        self
    }

    /// The same rule, for a query that wants an exact pass: it names no
    /// count of admitted rows, so the planner never takes the neighbour
    /// graph's candidates for it.
    pub fn exact(mut self) -> Self {
        self.admitted = None;
        self
    }
}

impl RowFilter for RowEligibility<'_> {
    #[inline]
    fn test(&self, row: usize) -> bool {
        RowEligibility::test(self, row)
    }

    fn partition(&self) -> Option<&[usize]> {
        let tracks = self.tracks.as_ref()?;
        let rows = self.partition.get_or_init(|| {
            let mut rows: Vec<usize> = track_rows(tracks).collect();
            rows.sort_unstable();
            rows
        });
        Some(rows)
    }

    fn for_each_tagged_in_partition(
        &self,
        mask: u32,
        tag: &dyn Fn(usize) -> u32,
        f: &mut dyn FnMut(usize),
    ) -> bool {
        let Some(maps) = &self.tracks else {
            return false;
        };
        if let Some(rows) = self.partition.get() {
            for_each_tagged(rows.iter().copied(), mask, tag, f);
            return true;
        }
        for map in maps {
            match map.sampled {
                // Every row the mask keeps is in the subset.
                Some(sampled) if mask & SAMPLED_MASK == SAMPLED_MASK => sampled
                    .iter()
                    .filter(|&(_, &t)| t & mask == 0)
                    .for_each(|(id, _)| f(map.track[id])),
                // A map whose subset is empty has none either.
                None if mask & SAMPLED_MASK == SAMPLED_MASK => {}
                _ => for_each_tagged(map.track.values().copied(), mask, tag, f),
            }
        }
        true
    }

    fn admitted(&self) -> Option<usize> {
        self.admitted
    }

    fn group(&self) -> Option<RowGroup> {
        self.group
    }
}

/// Every row of `maps`, track by track.
fn track_rows<'t>(maps: &'t [AdmittedMap<'_>]) -> impl Iterator<Item = usize> + 't {
    maps.iter().flat_map(|map| map.track.values().copied())
}
