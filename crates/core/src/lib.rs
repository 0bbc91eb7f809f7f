//! HuMem's core: what a place is and how places are compared, as plain data
//! and pure functions, with no I/O, no models and no network.
//!
//! Every other crate speaks these types; this one depends on none of them,
//! so scoring can be tested and benchmarked on its own, and a change to the
//! server, the store or the models can never reach into the scoring.
//!
//! - [`keyframe`]: the semantic keyframe of the paper and its owner (robot,
//!   session, map), the unit everything stores and ranks;
//! - [`vpr`]: HuMem-VPR scoring (SCAL, OSRL, OGTL, contradiction, fusion)
//!   and the ranking of one query;
//! - [`verdict`]: SLAM's geometric verdicts on proposed candidates, and
//!   the book that keeps them beside the index;
//! - [`index`]: the in-memory index the scan runs over, kept by the store;
//! - [`row_ids`]: interned robot and session ids, so the scan's eligibility
//!   test compares integers;
//! - [`observe`]: the hook through which queues report their depth and batch
//!   sizes, so lower layers never read the server's metrics;
//! - [`synthetic`]: fleet-shaped synthetic descriptors for the benchmarks
//!   and the load generator.

pub mod engine;
pub mod index;
#[cfg(test)]
mod index_scan_tests;
pub mod keyframe;
mod numeric;
pub mod observe;
pub mod query;
pub mod row_ids;
pub mod synthetic;
pub mod verdict;
pub mod vpr;
