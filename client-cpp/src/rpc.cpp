// Job: the gRPC plumbing declared in rpc.h.
#include "rpc.h"

#include <cstdlib>
#include <string>

namespace humem::internal {

std::string NormaliseTarget(const std::string& target) {
  static const char* const kPrefixes[] = {"http://", "grpc://"};
  for (const char* prefix : kPrefixes) {
    const std::string p(prefix);
    if (target.compare(0, p.size(), p) == 0) {
      std::string rest = target.substr(p.size());
      if (!rest.empty() && rest.back() == '/') rest.pop_back();
      return rest;
    }
  }
  return target;
}

std::shared_ptr<grpc::Channel> MakeChannel(const ClientOptions& options) {
  grpc::ChannelArguments args;
  const int reconnect_max = static_cast<int>(options.reconnect_backoff_max.count());
  const int reconnect_min = reconnect_max < 100 ? reconnect_max : 100;
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, reconnect_min);
  args.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, reconnect_min);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, reconnect_max);
  args.SetMaxReceiveMessageSize(options.max_message_bytes);
  args.SetMaxSendMessageSize(options.max_message_bytes);
  return grpc::CreateCustomChannel(NormaliseTarget(options.target), grpc::InsecureChannelCredentials(), args);
}

Status FromGrpc(const grpc::Status& status) {
  return Status(static_cast<StatusCode>(status.error_code()), status.error_message());
}

std::chrono::milliseconds RetryAfter(const grpc::ClientContext& context) {
  const std::multimap<grpc::string_ref, grpc::string_ref>& trailers = context.GetServerTrailingMetadata();
  auto it = trailers.find("retry-after-ms");
  if (it == trailers.end()) return std::chrono::milliseconds(0);
  const std::string value(it->second.data(), it->second.size());
  char* end = nullptr;
  const long long ms = std::strtoll(value.c_str(), &end, 10);
  if (end == value.c_str() || ms < 0) return std::chrono::milliseconds(0);
  // A hint longer than a minute is not believed.
  return std::chrono::milliseconds(ms > 60000 ? 60000 : ms);
}

void CallRegistry::Add(grpc::ClientContext* context) {
  std::lock_guard<std::mutex> lock(mutex_);
  calls_.insert(context);
  if (cancelled_) context->TryCancel();
}

void CallRegistry::Remove(grpc::ClientContext* context) {
  std::lock_guard<std::mutex> lock(mutex_);
  calls_.erase(context);
}

void CallRegistry::CancelAll() {
  std::lock_guard<std::mutex> lock(mutex_);
  cancelled_ = true;
  for (grpc::ClientContext* c : calls_) c->TryCancel();
}

}  // namespace humem::internal
