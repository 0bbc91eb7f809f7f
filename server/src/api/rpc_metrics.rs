//! Per-RPC metrics as one tower layer: each call of a `humem.v1` method is
//! counted by method and status code, and its latency observed, in one
//! place instead of a wrapper per handler.
//!
//! The layer sits in the transport, around the whole service, so it also
//! counts the calls tonic refuses before a handler runs (a body too large or
//! not protobuf). The code is read from the response headers: tonic answers
//! every failed unary call trailers-only, with `grpc-status` in the headers,
//! and a response without it is a success. A call whose caller goes away
//! first (its future dropped) is recorded as CANCELLED.

use std::task::{Context, Poll};
use std::time::Instant;

use futures::future::BoxFuture;
use tonic::codegen::http;
use tonic::Code;

use crate::metrics;

/// The gRPC path prefix of the API's methods.
const SERVICE_PREFIX: &str = "/humem.v1.PlaceRecognition/";

/// The method label of a request path; `None` for other services (health,
/// reflection) and unknown methods.
fn method_of(path: &str) -> Option<&'static str> {
    let method = path.strip_prefix(SERVICE_PREFIX)?;
    metrics::RPCS.into_iter().find(|m| *m == method)
}

/// The gRPC status of a response, from its headers (trailers-only) or OK.
fn code_of<B>(response: &http::Response<B>) -> Code {
    response
        .headers()
        .get("grpc-status")
        .map_or(Code::Ok, |v| Code::from_bytes(v.as_bytes()))
}

/// The layer; add it to the server once.
#[derive(Debug, Clone, Copy, Default)]
pub struct RpcMetricsLayer;

impl<S> tower::Layer<S> for RpcMetricsLayer {
    type Service = RpcMetrics<S>;

    fn layer(&self, inner: S) -> RpcMetrics<S> {
        RpcMetrics { inner }
    }
}

/// A service with its calls measured.
#[derive(Debug, Clone)]
pub struct RpcMetrics<S> {
    inner: S,
}

impl<S, B, RB> tower::Service<http::Request<B>> for RpcMetrics<S>
where
    S: tower::Service<http::Request<B>, Response = http::Response<RB>>,
    S::Future: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = BoxFuture<'static, Result<S::Response, S::Error>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: http::Request<B>) -> Self::Future {
        let method = method_of(request.uri().path());
        let call = self.inner.call(request);
        let Some(method) = method else {
            return Box::pin(call);
        };
        Box::pin(async move {
            let observer = RpcObserver::start(method);
            let result = call.await;
            observer.finish(result.as_ref().map_or(Code::Internal, code_of));
            result
        })
    }
}

/// Records an RPC's latency and status code when it finishes, and as
/// CANCELLED if the caller went away first (its future was dropped).
struct RpcObserver {
    rpc: &'static str,
    started: Instant,
    done: bool,
}

impl RpcObserver {
    fn start(rpc: &'static str) -> RpcObserver {
        RpcObserver {
            rpc,
            started: Instant::now(),
            done: false,
        }
    }

    fn finish(mut self, code: Code) {
        metrics::observe_rpc(self.rpc, code, self.started.elapsed().as_secs_f64());
        self.done = true;
    }
}

impl Drop for RpcObserver {
    fn drop(&mut self) {
        if !self.done {
            metrics::observe_rpc(
                self.rpc,
                Code::Cancelled,
                self.started.elapsed().as_secs_f64(),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_apis_methods_are_measured() {
        assert_eq!(method_of("/humem.v1.PlaceRecognition/Query"), Some("Query"));
        assert_eq!(
            method_of("/humem.v1.PlaceRecognition/InsertBatch"),
            Some("InsertBatch")
        );
        assert_eq!(method_of("/humem.v1.PlaceRecognition/Nope"), None);
        assert_eq!(method_of("/grpc.health.v1.Health/Check"), None);
    }

    #[test]
    fn the_code_comes_from_the_headers_or_is_ok() {
        let ok = http::Response::new(());
        assert_eq!(code_of(&ok), Code::Ok);
        let mut failed = http::Response::new(());
        failed
            .headers_mut()
            .insert("grpc-status", http::HeaderValue::from_static("3"));
        assert_eq!(code_of(&failed), Code::InvalidArgument);
    }
}
