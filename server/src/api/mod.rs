//! The gRPC face of the service, a thin adapter over the pipeline.
//!
//! - [`validate`]: protobuf requests in, domain values out, every field
//!   checked and named in errors;
//! - [`service`]: the tonic service: validate, call the pipeline, convert;
//! - [`convert`]: domain answers and errors to protobuf and gRPC statuses;
//! - [`rpc_metrics`]: the tower layer that counts and times every call;
//! - [`transport_status`]: tonic's own statuses mapped to the API's.

pub mod convert;
pub mod rpc_metrics;
pub mod service;
pub mod transport_status;
pub mod validate;

pub use service::PlaceRecognitionService;

#[cfg(test)]
mod fuzz_tests;
