//! SLAM's verdicts kept beside the index, the operating point they give,
//! and where stored keyframes are (their map's keyframe spacing and the
//! keyframes near a place), which is what the verdicts' place tests read.

use std::sync::PoisonError;

use crate::keyframe::KeyframeKey;
use crate::verdict::{Verdict, VerdictBook, VerificationKind};
use crate::vpr::feedback::{Place, VerdictParams};
use crate::vpr::operating_point::{self, OperatingPoint, Sample};
use crate::vpr::params::VprParams;

use super::table::{CachedPoint, Index, MapKey};

/// Seconds an estimated operating point is reused while no verdict
/// changes: the verdicts' weights decay over days, so a minute moves
/// nothing that matters, and a busy server estimates it once a minute
/// instead of once a query.
pub const OPERATING_POINT_REFRESH_S: f64 = 60.0;

impl Index {
    /// The stored verdicts.
    pub fn verdicts(&self) -> &VerdictBook {
        &self.verdicts
    }

    /// Records a verdict (the store has checked that both of its keyframes
    /// are stored); says whether it replaced one on the same pair and kind.
    pub fn record_verdict(&mut self, verdict: Verdict) -> bool {
        self.forget_operating_point();
        self.verdicts.record(verdict)
    }

    /// The store's operating point at `now` (seconds since the epoch):
    /// the threshold a query that names none gets, adapted from the
    /// scored verdicts by [`operating_point`] when
    /// `vpr.verdicts.enabled` and `adapt_threshold` are on, else the
    /// configured one. Reused for [`OPERATING_POINT_REFRESH_S`] while no
    /// verdict changes.
    pub fn operating_point(&self, params: &VprParams, now: f64) -> OperatingPoint {
        let base = params.threshold();
        let verdict_params = &params.verdicts;
        if !(verdict_params.enabled && verdict_params.adapt_threshold) {
            return OperatingPoint::fixed(base);
        }
        let mut cache = self
            .operating_point
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(c) = cache.as_ref() {
            if c.base == base
                && c.params == *verdict_params
                && (now - c.at).abs() < OPERATING_POINT_REFRESH_S
            {
                return c.point;
            }
        }
        let samples: Vec<Sample> = self
            .verdicts
            .iter()
            .filter(|v| v.kind != VerificationKind::Relocalisation)
            .filter_map(|v| {
                Some(Sample {
                    score: v.score?,
                    accepted: v.accepted,
                    weight: verdict_params.weight(v.reported_at, now),
                })
            })
            .collect();
        let point = operating_point::adapt(&verdict_params.rule(base), &samples);
        *cache = Some(CachedPoint {
            params: verdict_params.clone(),
            base,
            at: now,
            point,
        });
        point
    }

    /// Drops the cached operating point (the verdicts changed).
    pub(super) fn forget_operating_point(&mut self) {
        *self
            .operating_point
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner) = None;
    }

    /// Where a stored keyframe is (its map and camera centre), for the
    /// verdicts' place tests.
    pub fn place<'a>(&'a self, key: &KeyframeKey) -> Option<Place<'a>> {
        Some(self.place_of_row(self.row_of(key)?))
    }

    /// The stored keyframes at `place`'s place: those of its map at most
    /// `radius` from it (itself among them when stored). One pass over
    /// that map's rows, a few flops each: far less than the query's scan
    /// of the same rows.
    pub fn keyframes_near<'a>(
        &'a self,
        place: &Place,
        params: &VerdictParams,
    ) -> Vec<&'a KeyframeKey> {
        let map = MapKey {
            session: place.key.session(),
            map_id: place.map_id,
        };
        let radius = params.radius(place.spacing);
        self.tracks
            .get(&map)
            .into_iter()
            .flat_map(|track| track.values())
            .map(|&row| self.place_with_spacing(row, place.spacing))
            .filter(|other| place.within(other, radius))
            .map(|other| other.key)
            .collect()
    }

    /// `s`, a map's keyframe spacing: the median distance between the
    /// stored positions of its consecutive keyframes (by keyframe id); 0
    /// for an unknown map or one of a single keyframe. The verdicts'
    /// same-place radius is measured in it ([`feedback`](crate::vpr::feedback)), since a
    /// map's units need not be metres. The median of the map's kept track
    /// steps ([`paths`](super::paths)), once per change of the map, cached.
    pub fn map_spacing(&self, map: &MapKey) -> f64 {
        let mut cache = self.spacings.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(&spacing) = cache.get(map) {
            return spacing;
        }
        let Some(mut steps) = self.track_path(map, |path| path.steps().to_vec()) else {
            return 0.0;
        };
        let spacing = if steps.is_empty() {
            0.0
        } else {
            let middle = steps.len() / 2;
            *steps.select_nth_unstable_by(middle, f64::total_cmp).1
        };
        cache.insert(map.clone(), spacing);
        spacing
    }

    /// Drops a map's cached spacing (its track or a pose in it changed).
    pub(super) fn forget_spacing(&mut self, map: &MapKey) {
        self.spacings
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner)
            .remove(map);
    }

    /// Where the keyframe of `row` is. Panics if `row` is out of range.
    pub fn place_of_row(&self, row: usize) -> Place<'_> {
        self.place_with_spacing(row, self.map_spacing(&self.rows[row].map_key()))
    }

    /// The place of `row` in a map whose spacing is already known.
    fn place_with_spacing(&self, row: usize, spacing: f64) -> Place<'_> {
        let meta = &self.rows[row];
        Place {
            key: &meta.key,
            map_id: meta.map_id,
            position: meta.pose.translation,
            spacing,
        }
    }
}
