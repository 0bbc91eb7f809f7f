//! Statuses tonic's transport produces inside the service, mapped to the
//! ones our API promises.
//!
//! A request larger than `server.max_message_bytes` is refused before
//! decoding with OUT_OF_RANGE; for a client that is a bad request like any
//! other, so it becomes INVALID_ARGUMENT naming the setting. Our handlers
//! never return OUT_OF_RANGE, so only tonic's own status is rewritten.
//!
//! (A client deadline that expires ends the request in tonic's outermost
//! layer, with CANCELLED "Timeout expired", out of reach of this mapper;
//! gRPC clients that enforce their deadline themselves, like gRPC C++,
//! report DEADLINE_EXCEEDED on their side.)

use tonic::codegen::http;

/// The text tonic puts in the status of an oversize request.
const TONIC_OVERSIZE: &[u8] = b"decoded message length too large";

/// Rewrites tonic's oversize-request status; every other response passes.
pub fn map_transport_status<B>(mut response: http::Response<B>) -> http::Response<B> {
    let headers = response.headers_mut();
    let is_oversize = headers.get("grpc-status").map(|v| v.as_bytes()) == Some(b"11")
        && headers.get("grpc-message").is_some_and(|m| {
            m.as_bytes()
                .windows(TONIC_OVERSIZE.len())
                .any(|w| w == TONIC_OVERSIZE)
        });
    if is_oversize {
        let original = headers
            .get("grpc-message")
            .and_then(|m| m.to_str().ok())
            .unwrap_or_default()
            .trim_start_matches("Error, ")
            .to_string();
        let message = format!("request: {original} (server.max_message_bytes)");
        headers.insert("grpc-status", http::HeaderValue::from_static("3"));
        if let Ok(value) = http::HeaderValue::from_str(&message) {
            headers.insert("grpc-message", value);
        }
    }
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    fn response(status: &'static str, message: &'static str) -> http::Response<()> {
        let mut r = http::Response::new(());
        r.headers_mut()
            .insert("grpc-status", http::HeaderValue::from_static(status));
        r.headers_mut()
            .insert("grpc-message", http::HeaderValue::from_static(message));
        r
    }

    #[test]
    fn only_the_oversize_status_is_rewritten() {
        let r = map_transport_status(response(
            "11",
            "Error, decoded message length too large: found 20 bytes, the limit is: 10 bytes",
        ));
        assert_eq!(r.headers()["grpc-status"], "3");
        assert_eq!(
            r.headers()["grpc-message"],
            "request: decoded message length too large: found 20 bytes, the limit is: 10 bytes (server.max_message_bytes)"
        );
        let r = map_transport_status(response("11", "something else"));
        assert_eq!(r.headers()["grpc-status"], "11");
        let r = map_transport_status(response("5", "decoded message length too large"));
        assert_eq!(r.headers()["grpc-status"], "5");
    }
}
