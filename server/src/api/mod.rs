//! The gRPC face of the service: validation of requests, conversion of
//! answers, and the tonic service that ties them to the store and pipeline.

pub mod convert;
pub mod service;
pub mod transport_status;
pub mod validate;

pub use service::PlaceRecognitionService;
