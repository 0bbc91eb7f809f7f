//! The evaluation harness behind `humem eval`: the paper's protocol
//! (DESIGN.md, "Evaluation protocol") on real images, and the benchmarks
//! behind `humem bench`.
//!
//! It sits above the server crate, so that it can measure the service's own
//! code in process or a running service over gRPC, and so that the service
//! builds without it (no plotting, progress bars or ORB baseline in a
//! deployment; the `humem` binary takes it in with its `eval` feature).
//!
//! - [`annotations`]: ground-truth objects from instance masks (`--objects annotations`);
//! - [`baseline`]: the ORB bag-of-words baseline ORB-SLAM3 uses (`humem-orb-bow`);
//! - [`dataset`]: data set folders and where their ground truth comes from;
//! - [`source`]: recordings (bags, TUM, EuRoC, KITTI) as data set folders (`--source`);
//! - [`truth`]: ground truth files, pose files and the paper's pose rule;
//! - [`metrics`]: Recall@K, MRR, query selection and latency statistics;
//! - [`precision`]: false alarms, candidate precision, recall at 100 %
//!   precision and the precision–recall curve at the operating point;
//! - [`degrade`]: the motion blur and exposure reduction of the conditions;
//! - [`plots`]: the report's charts (accuracy–latency, recall per condition);
//! - [`ingest`]: a recording streamed into a running server, its loop
//!   candidates scored (`humem ingest`);
//! - [`remote`]: the run measured through a service over gRPC (`--server`);
//! - [`run`]: the run itself, its table, JSON and report;
//! - [`text_recall`]: how often OCR reads the signs in view (`humem text-recall`);
//! - [`verdict_replay`]: the stream replayed with the ground truth as
//!   geometric verification, without and with verdicts (`--replay-verdicts`);
//! - [`perception_bench`]: time per model and batch size (`humem bench perception`);
//! - [`verdict_bench`]: what stored verdicts add to a query's cost
//!   (`humem bench verdicts`).

pub mod annotations;
pub mod baseline;
pub mod dataset;
pub mod degrade;
pub mod ingest;
pub mod metrics;
pub mod perception_bench;
pub mod plots;
pub mod precision;
pub mod remote;
pub mod restart_bench;
pub mod run;
pub mod scan_bench;
pub mod source;
pub mod text_recall;
pub mod truth;
pub mod verdict_bench;
pub mod verdict_replay;

/// `humem bench perception`'s old path: the binary's `main.rs` still calls
/// `humem_eval::bench::perception`.
#[doc(hidden)]
pub use perception_bench as bench;
