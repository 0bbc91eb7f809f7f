//! Statuses tonic's transport produces inside the service, mapped to the
//! ones our API promises.
//!
//! A request larger than `server.max_message_bytes` is refused before
//! decoding with OUT_OF_RANGE, and a body that is not protobuf gets
//! INTERNAL from the codec; for a client both are bad requests like any
//! other, so they become INVALID_ARGUMENT (the first naming the setting).
//! They are told apart from our handlers' own statuses by code and text:
//! our handlers never return OUT_OF_RANGE, nor INTERNAL with prost's text.
//!
//! (A client deadline that expires ends the request in tonic's outermost
//! layer, with CANCELLED "Timeout expired", out of reach of this mapper;
//! gRPC clients that enforce their deadline themselves, like gRPC C++,
//! report DEADLINE_EXCEEDED on their side.)

use tonic::codegen::http;
use tonic::Code;

/// The text tonic puts in the status of an oversize request.
const TONIC_OVERSIZE: &str = "decoded message length too large";
/// The text prost's decoder error starts with (tonic answers it INTERNAL).
const PROST_DECODE: &str = "failed to decode Protobuf message";

/// Rewrites tonic's statuses for bad request bodies; every other response
/// passes untouched.
pub fn map_transport_status<B>(mut response: http::Response<B>) -> http::Response<B> {
    let headers = response.headers_mut();
    let code = headers.get("grpc-status").map(|v| v.as_bytes());
    let message = || {
        headers
            .get("grpc-message")
            .map(|m| {
                percent_encoding::percent_decode(m.as_bytes())
                    .decode_utf8_lossy()
                    .into_owned()
            })
            .unwrap_or_default()
    };
    let rewritten = match code {
        Some(b"11") if message().contains(TONIC_OVERSIZE) => Some(format!(
            "request: {} (server.max_message_bytes)",
            message().trim_start_matches("Error, ")
        )),
        Some(b"13") if message().starts_with(PROST_DECODE) => Some(format!(
            "request: the body is not a valid message of this RPC ({})",
            message()
        )),
        _ => None,
    };
    if let Some(message) = rewritten {
        // `add_header` percent-encodes the message as gRPC requires.
        let _ = tonic::Status::new(Code::InvalidArgument, message).add_header(headers);
    }
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A response carrying `status` as tonic writes it (message
    /// percent-encoded).
    fn response(code: Code, message: &str) -> http::Response<()> {
        let mut r = http::Response::new(());
        tonic::Status::new(code, message)
            .add_header(r.headers_mut())
            .unwrap();
        r
    }

    fn status(r: &http::Response<()>) -> tonic::Status {
        tonic::Status::from_header_map(r.headers()).unwrap()
    }

    #[test]
    fn only_bad_request_bodies_are_rewritten() {
        let r = map_transport_status(response(
            Code::OutOfRange,
            "Error, decoded message length too large: found 20 bytes, the limit is: 10 bytes",
        ));
        let s = status(&r);
        assert_eq!(s.code(), Code::InvalidArgument);
        assert_eq!(
            s.message(),
            "request: decoded message length too large: found 20 bytes, the limit is: 10 bytes (server.max_message_bytes)"
        );
        let r = map_transport_status(response(
            Code::Internal,
            "failed to decode Protobuf message: invalid wire type value: 7",
        ));
        let s = status(&r);
        assert_eq!(s.code(), Code::InvalidArgument);
        assert_eq!(
            s.message(),
            "request: the body is not a valid message of this RPC (failed to decode Protobuf message: invalid wire type value: 7)"
        );
        for (code, message) in [
            (Code::OutOfRange, "something else"),
            (Code::NotFound, "decoded message length too large"),
            (Code::Internal, "flushing the store failed"),
        ] {
            let s = status(&map_transport_status(response(code, message)));
            assert_eq!((s.code(), s.message()), (code, message));
        }
    }
}
