// Job: the gRPC plumbing shared by the writer, the query lanes and the
// facade: the channel (with short reconnection back-off), gRPC status ->
// humem::Status, the server's retry-after-ms hint, and a registry of the
// calls in flight so that Close() can cancel them.
#ifndef HUMEM_SRC_RPC_H_
#define HUMEM_SRC_RPC_H_

#include <chrono>
#include <memory>
#include <mutex>
#include <set>
#include <string>

#include <grpcpp/grpcpp.h>

#include "humem/status.h"
#include "humem/vpr_client.h"

namespace humem::internal {

// "http://host:port", "https://host:port" -> "host:port"; other targets
// pass unchanged.
std::string NormaliseTarget(const std::string& target);

// Whether the target asks for TLS ("https://").
bool UsesTls(const std::string& target);

// The channel credentials the options ask for: TLS with the CA, client
// certificate and key read from their files for an "https://" target,
// plaintext otherwise. INVALID_ARGUMENT naming the option when a file
// cannot be read or the TLS options do not fit the target.
Status MakeCredentials(const ClientOptions& options, std::shared_ptr<grpc::ChannelCredentials>* credentials);

std::shared_ptr<grpc::Channel> MakeChannel(const ClientOptions& options,
                                           const std::shared_ptr<grpc::ChannelCredentials>& credentials);

Status FromGrpc(const grpc::Status& status);

// The server's `retry-after-ms` hint of a finished call (trailing metadata,
// where tonic's trailers-only error responses land), or 0.
std::chrono::milliseconds RetryAfter(const grpc::ClientContext& context);

// Calls in flight, so that Close() can cancel them. Once CancelAll() has run,
// Add() cancels a new context at once (a call started during shutdown ends
// immediately instead of waiting for its deadline).
class CallRegistry {
 public:
  void Add(grpc::ClientContext* context);
  void Remove(grpc::ClientContext* context);
  void CancelAll();

 private:
  std::mutex mutex_;
  std::set<grpc::ClientContext*> calls_;
  bool cancelled_ = false;
};

// Registers a context for the duration of one call.
class ScopedCall {
 public:
  ScopedCall(CallRegistry* registry, grpc::ClientContext* context) : registry_(registry), context_(context) {
    registry_->Add(context_);
  }
  ~ScopedCall() { registry_->Remove(context_); }
  ScopedCall(const ScopedCall&) = delete;
  ScopedCall& operator=(const ScopedCall&) = delete;

 private:
  CallRegistry* registry_;
  grpc::ClientContext* context_;
};

}  // namespace humem::internal

#endif  // HUMEM_SRC_RPC_H_
