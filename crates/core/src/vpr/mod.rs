//! HuMem-VPR: the paper's scoring layers and the rules on top of them,
//! which rank stored semantic keyframes against a query.
//!
//! Everything here is a pure function over plain data (no I/O, no models, no
//! server), so the scoring can be unit-tested and benchmarked on its own. It
//! reads the stored rows through the [`crate::engine`] below it and through
//! [`memory::KeyframeMemory`], so the in-memory index above it is only one
//! of the stores it can rank. The layers follow the paper
//! (`docs/scoring.md` has every formula and constant):
//!
//! - [`scal`]: global-descriptor cosine (blended with the [`appearance`]
//!   thumbnails' similarity), scene modulation and temporal context (the
//!   scene-primary hypothesis); [`scan`] is its pass over the whole eligible
//!   store, exact or on the codes, on every core;
//! - [`osrl`](mod@osrl): object layout, per-class Hungarian assignment, on the top K;
//! - [`ogtl`](mod@ogtl): OCR text grounded on spatially compatible objects, on the top K;
//! - [`contradiction`]: evidence against a candidate, `C` (disagreeing
//!   distinctive text, missing distinctive objects), on the top K;
//! - [`calibration`]: the scene score calibrated against the query's null
//!   distribution, so one threshold serves any descriptor model;
//! - [`fusion`]: bounded corroboration `B` and the fused score `Λ`;
//! - [`rank`](mod@rank): the orchestration of one query's ranking and the
//!   final selection.
//!
//! The rules on top of the paper: [`feedback`] (what SLAM's geometric
//! verdicts do to a ranking: known look-alikes lose score, verified places
//! gain it), [`operating_point`] (the threshold those verdicts estimate),
//! [`viewpoint`] (views of the query's own map turned away from it),
//! [`drift`] (candidates of the query's own map farther away than the
//! map's drift explains).
//!
//! Supporting modules: [`params`] (every constant, configurable),
//! [`eligibility`] (which stored keyframes may be proposed), [`memory`] (the
//! view of the store that ranking needs), [`text`] (string similarity and
//! distinctiveness) and `assignment` (the Hungarian solver adapter).
//!
//! Each item has one public path, its module's (`vpr::rank::select`); the
//! modules import each other directly, never through this one.

pub mod appearance;
mod assignment;
pub mod calibration;
pub mod contradiction;
pub mod drift;
pub mod eligibility;
pub mod feedback;
pub mod fusion;
pub mod memory;
pub mod ogtl;
pub mod operating_point;
pub mod osrl;
pub mod params;
pub(crate) mod piecewise;
mod query_side;
pub mod rank;
pub mod scal;
pub mod scan;
pub mod text;
pub mod viewpoint;

#[cfg(test)]
pub(crate) mod testing;
