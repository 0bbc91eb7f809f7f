//! HuMem's gRPC service: the API, the orchestration of each request, the
//! configuration, the metrics, and the server that wires them together.
//!
//! This crate is the service's top layer. Below it, and unaware of it, sit
//! `humem-core` (keyframes, scoring, the index), `humem-store` (sled),
//! `humem-cluster` (the replicated write log of cluster mode) and
//! `humem-perception` (the models); above it only the `humem` binary and
//! the evaluation harness. Within it, each module depends only on those
//! listed after it:
//!
//! - [`server`]: builds the store, perception and service from a
//!   [`config::Config`], serves gRPC (with health and reflection) and
//!   metrics, and shuts down cleanly;
//! - [`api`]: the tonic service, a thin adapter: validates a request,
//!   checks who asks ([`auth`]) and how often ([`quota`]), hands it to the
//!   pipeline, converts the answer;
//! - [`auth`]: credentials (tokens, client certificates), who may act for
//!   which robot and read which maps, the audit trail;
//! - [`quota`]: per-robot insert and query rates and store size;
//! - [`tls`]: TLS on the gRPC port, reloaded when its files change;
//! - `watch`: notices that a file (certificates, the token file) changed;
//! - [`pipeline`]: what one request does, in domain types: admission, image
//!   resolution, blocking work, the query over the index
//!   ([`humem_core::query`] does its index-level end), latest-wins;
//! - [`metrics`]: the Prometheus metrics and their HTTP endpoint;
//! - [`config`]: every setting, from TOML and `HUMEM_*` variables, validated;
//! - [`client`]: connecting to a server, for this workspace's own clients;
//! - [`proto`]: the generated API types and services.
//!
//! `tools/check_module_graph.py` (run by the test command) keeps each
//! crate's modules free of import circles.

pub mod api;
pub mod auth;
pub mod client;
pub mod config;
pub mod metrics;
pub mod pipeline;
pub mod quota;
pub mod server;
pub mod tls;
mod watch;

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
