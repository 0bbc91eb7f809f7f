//! HuMem-VPR scoring: ranks stored semantic keyframes against a query.
//!
//! Everything here is a pure function over plain data (no I/O, no models, no
//! server), so the scoring can be unit-tested and benchmarked on its own. The
//! layers follow the paper and `DESIGN.md`:
//!
//! - [`scal`]: global-descriptor cosine (blended with the [`appearance`]
//!   thumbnails' similarity), scene modulation and temporal context (the
//!   scene-primary hypothesis), over the whole eligible store;
//! - [`osrl`](mod@osrl): object layout, per-class Hungarian assignment, on the top K;
//! - [`ogtl`](mod@ogtl): OCR text grounded on spatially compatible objects, on the top K;
//! - [`contradiction`]: evidence against a candidate, `C` (disagreeing
//!   distinctive text, missing distinctive objects), on the top K;
//! - [`calibration`]: the scene score calibrated against the query's null
//!   distribution, so one threshold serves any descriptor model;
//! - [`fusion`]: bounded corroboration `B` and the fused score `Λ`;
//! - [`feedback`]: what SLAM's geometric verdicts do to a ranking (known
//!   look-alikes lose score, verified places gain it);
//! - [`rank`](mod@rank): the orchestration of one query and the final selection.
//!
//! Supporting modules: [`params`] (every constant, configurable),
//! [`eligibility`] (which stored keyframes may be proposed), [`matrix`] (the
//! contiguous descriptor matrix the scan runs over), [`codes`] (its one-byte
//! codes with error bounds), [`kernels`] (the SIMD inner loops), [`row_file`] (where the f32
//! rows go when they leave memory), [`scan`]
//! (SCAL's pass over the store, exact or on the codes, on every core),
//! [`memory`] (the view of
//! the store that ranking needs), [`text`] (string similarity and
//! distinctiveness) and `assignment` (the Hungarian solver adapter).

pub mod appearance;
mod assignment;
pub mod calibration;
pub mod codes;
pub mod contradiction;
pub mod eligibility;
pub mod feedback;
pub mod filter;
pub mod fusion;
pub mod kernels;
pub mod matrix;
pub mod memory;
pub mod ogtl;
pub mod operating_point;
pub mod osrl;
pub mod params;
pub mod rank;
pub mod row_file;
pub mod scal;
pub mod scan;
pub mod text;
pub mod viewpoint;

#[cfg(test)]
pub(crate) mod testing;

pub use calibration::NullModel;
pub use contradiction::{Contradiction, MissingObject, TextConflict};
pub use eligibility::{is_eligible, CandidateMeta, MapRef, QueryContext, Scope};
pub use feedback::{VerdictEffect, VerdictParams};
pub use filter::RowFilter;
pub use fusion::{corroboration, fuse, fuse_with_contradiction};
pub use matrix::{dot, DescriptorMatrix};
pub use memory::{KeyframeMemory, VecMemory};
pub use ogtl::{ogtl, text_profile, text_profile_in, OgtlResult, TextMatch, TextProfile};
pub use operating_point::OperatingPoint;
pub use osrl::{object_affinity, osrl, spatial_kernel, ObjectMatch, OsrlResult};
pub use params::{Calibration, Layers, ScanMode, TemporalMode, VprParams};
pub use rank::{
    rank, rank_timed, select, sort_ranked, QueryObservation, RankedCandidate, Ranking, StageTimes,
};
pub use scal::{cosine, modulated, scal_scores, scene_compatibility, ScalHit, ScalQuery};
pub use scan::{scal_scan, ScalScan};
pub use text::{distinctiveness, string_similarity};

/// `clip(x, 0, 1)`, with NaN mapped to 0 and −0 to +0 so that scores always
/// order sensibly.
pub(crate) fn clip01(x: f32) -> f32 {
    if x > 0.0 {
        x.min(1.0)
    } else {
        0.0
    }
}

/// Copies of the rows `order` lists, in that order, from a row-major table
/// of `stride` values a row: the read-only half of a reordering
/// (descriptor codes, thumbnails).
pub(crate) fn gather_rows<T: Copy>(data: &[T], stride: usize, order: &[usize]) -> Vec<T> {
    let mut gathered = Vec::with_capacity(order.len() * stride);
    for &row in order {
        gathered.extend_from_slice(&data[row * stride..(row + 1) * stride]);
    }
    gathered
}
