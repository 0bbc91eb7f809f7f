//! HuMem's core: what a place is and how places are compared, as plain data
//! and functions, with no models and no network. Its one I/O is the file
//! the descriptor rows may move to when they leave memory
//! ([`engine::row_file`]).
//!
//! Every other crate speaks these types; this one depends on none of them,
//! so scoring can be tested and benchmarked on its own, and a change to the
//! server, the store or the models can never reach into the scoring. Its
//! modules form layers, each using only those below it:
//!
//! - [`query`]: one query over the index, from the eligible rows to the
//!   selected candidates (the ranking, then the rules on top of it that need
//!   the index: views turned away, SLAM's verdicts, the operating point);
//! - [`index`]: the in-memory index the scan runs over, kept by the store;
//! - [`row_ids`]: interned robot and session ids, so the scan's eligibility
//!   test compares integers;
//! - [`vpr`]: HuMem-VPR, the paper's layers (SCAL and its scan, OSRL, OGTL,
//!   contradiction, calibration, fusion), the ranking of one query, and the
//!   rules on top (verdicts' feedback, operating point, viewpoint);
//! - [`engine`]: the scan engine, where the descriptors live (matrix,
//!   one-byte codes, the file rows move to) and the SIMD kernels that read
//!   them;
//! - [`verdict`]: SLAM's geometric verdicts on proposed candidates, and
//!   the book that keeps them beside the index;
//! - [`keyframe`]: the semantic keyframe of the paper and its owner (robot,
//!   session, map), the unit everything stores and ranks;
//! - `numeric`: the small numeric helpers the layers share;
//! - [`observe`]: the hook through which queues report their depth and batch
//!   sizes, so lower layers never read the server's metrics;
//! - [`synthetic`]: fleet-shaped synthetic descriptors for the benchmarks
//!   and the load generator.
//!
//! A new scoring rule that needs only the ranked rows goes into [`vpr`]
//! (with its constant in [`vpr::params`]); one that needs the index (poses,
//! maps, verdicts) into [`query`].

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
