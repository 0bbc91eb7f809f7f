//! Orchestration of one request: from validated domain values to an answer,
//! over the store's index and the HuMem-VPR scoring. Knows nothing of gRPC.

pub mod latest_wins;
pub mod query;
