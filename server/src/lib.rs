//! HuMem: semantic place recognition for visual SLAM, as a gRPC service.
//!
//! Layers, each depending only on those below it:
//! - [`api`]: the tonic service, request validation, proto ⇄ domain conversion;
//! - [`pipeline`]: the orchestration of one request over the store and scoring;
//! - [`perception`]: the ONNX models that turn images into features;
//! - [`vpr`]: HuMem-VPR scoring and ranking, pure functions over plain data;
//! - [`store`]: durable sled storage and the in-memory search index;
//! - [`keyframe`]: the semantic keyframe all of them speak.
//!
//! [`server`] wires them into a running service, [`cli`] is the command-line
//! client and [`config`] the configuration.

pub mod api;
pub mod bench;
pub mod cli;
pub mod config;
pub mod eval;
pub mod keyframe;
pub mod metrics;
pub mod perception;
pub mod pipeline;
pub mod server;
pub mod store;
pub mod vpr;

/// The generated gRPC API (`proto/humem/v1/humem.proto`), with its proto3
/// JSON mapping for the command-line client.
pub mod proto {
    #![allow(clippy::all, missing_docs)]
    tonic::include_proto!("humem.v1");
    include!(concat!(env!("OUT_DIR"), "/humem.v1.serde.rs"));

    /// Encoded descriptors of the API, for gRPC server reflection.
    pub const FILE_DESCRIPTOR_SET: &[u8] =
        include_bytes!(concat!(env!("OUT_DIR"), "/humem_descriptor.bin"));
}
