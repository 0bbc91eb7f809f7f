//! The evaluation harness behind `humem eval`: the paper's protocol
//! (docs/evaluation.md) on real images, and the benchmarks
//! behind `humem bench`.
//!
//! It sits above the server crate, so that it can measure the service's own
//! code in process or a running service over gRPC, and so that the service
//! builds without it (no plotting, progress bars or ORB baseline in a
//! deployment; the `humem` binary takes it in with its `eval` feature).
//!
//! Its modules are layered, no circles: leaves first, each used only by the
//! ones after it (`tools/check_module_graph.py` checks it).
//!
//! Data sets and ground truth:
//! - [`truth`]: ground truth files, pose files and the paper's pose rule;
//! - [`dataset`]: data set folders and where their ground truth comes from;
//! - [`source`]: recordings (bags, TUM, EuRoC, KITTI) as data set folders (`--source`);
//! - [`annotations`]: ground-truth objects from instance masks (`--objects annotations`);
//! - [`degrade`]: the motion blur and exposure reduction of the conditions;
//!
//! Shared leaves of the harness:
//! - [`metrics`]: Recall@K, MRR, query selection and latency statistics;
//! - [`precision`]: false alarms, candidate precision, recall at 100 %
//!   precision and the precision–recall curve at the operating point;
//! - `progress`: the progress bar of every long pass;
//! - `images`: an image as a method is given it (degraded, grey);
//! - `keyframes`: an image as an index stores it;
//! - [`pose_drift`]: poses as a drifting odometry would send them
//!   (`--replay-pose-drift`);
//!
//! `humem eval`, bottom up:
//! - [`replay_rows`]: the replay's rows and their tables;
//! - [`replay_variant`]: a replay pass's further settings (`--replay-variant`);
//! - [`replay_steps`]: what a replay sends, step by step;
//! - [`verdict_replay`]: the stream replayed with the ground truth as
//!   geometric verification, without and with verdicts (`--replay-verdicts`);
//! - [`sent_log`]: what the ORB-SLAM3 plugin sent, as a replay's steps
//!   (`--replay-trajectory`);
//! - [`args`]: its options and the layer configurations they name;
//! - [`report`]: its numbers per method and condition, and their tables;
//! - [`protocol`]: the queries a run asks and what each method answered;
//! - [`plots`]: the report's charts (accuracy–latency, recall per condition,
//!   precision–recall);
//! - [`baseline`]: the ORB bag-of-words baseline ORB-SLAM3 uses (`humem-orb-bow`);
//! - `local`: the in-process database, ranking through the service's query path;
//! - [`remote`]: the run measured through a service over gRPC (`--server`);
//! - [`run`]: the run itself: backend, conditions, methods, outputs;
//!
//! The other commands:
//! - [`ingest`]: a recording streamed into a running server, its loop
//!   candidates scored (`humem ingest`);
//! - [`text_recall`]: how often OCR reads the signs in view (`humem text-recall`);
//! - [`perception_bench`]: time per model and batch size (`humem bench perception`);
//! - [`scan_bench`]: a SCAL-only query on a large store against an exact
//!   f32 scan (`humem bench scan`);
//! - [`restart_bench`]: opening a large store from its snapshot against a
//!   rebuild (`humem bench restart`);
//! - [`verdict_bench`]: what stored verdicts add to a query's cost
//!   (`humem bench verdicts`).

pub mod annotations;
pub mod args;
pub mod baseline;
pub mod dataset;
pub mod degrade;
pub mod graph_bench;
mod images;
pub mod ingest;
mod keyframes;
mod local;
pub mod metrics;
pub mod perception_bench;
pub mod plots;
pub mod pose_drift;
pub mod precision;
mod progress;
pub mod protocol;
pub mod remote;
pub mod replay_rows;
pub mod replay_steps;
pub mod replay_variant;
pub mod report;
pub mod restart_bench;
pub mod run;
pub mod scan_bench;
pub mod sent_log;
pub mod source;
pub mod text_recall;
pub mod truth;
pub mod verdict_bench;
pub mod verdict_replay;
