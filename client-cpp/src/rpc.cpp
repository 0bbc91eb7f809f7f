// Job: the gRPC plumbing declared in rpc.h.
#include "rpc.h"

#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>

namespace humem::internal {

std::string NormaliseTarget(const std::string& target) {
  static const char* const kPrefixes[] = {"http://", "https://", "grpc://"};
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

bool UsesTls(const std::string& target) { return target.compare(0, 8, "https://") == 0; }

namespace {

bool ReadFile(const std::string& path, std::string* contents) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  std::ostringstream buffer;
  buffer << in.rdbuf();
  *contents = buffer.str();
  return static_cast<bool>(in) || in.eof();
}

}  // namespace

Status MakeCredentials(const ClientOptions& options, std::shared_ptr<grpc::ChannelCredentials>* credentials) {
  auto invalid = [](const std::string& m) { return Status(StatusCode::kInvalidArgument, "ClientOptions." + m); };
  const bool tls_options = !options.tls_ca_file.empty() || !options.tls_cert_file.empty() ||
                           !options.tls_key_file.empty() || !options.tls_server_name.empty();
  if (!UsesTls(options.target)) {
    if (tls_options) return invalid("tls_*: set, but target " + options.target + " is not an https:// URL");
    if (!options.auth_token.empty()) {
      return invalid("auth_token: only sent over TLS, and target " + options.target + " is not an https:// URL");
    }
    *credentials = grpc::InsecureChannelCredentials();
    return Status::Ok();
  }
  if (options.tls_cert_file.empty() != options.tls_key_file.empty()) {
    return invalid("tls_cert_file/tls_key_file: give both or neither");
  }
  grpc::SslCredentialsOptions ssl;
  if (!options.tls_ca_file.empty() && !ReadFile(options.tls_ca_file, &ssl.pem_root_certs)) {
    return invalid("tls_ca_file: cannot read " + options.tls_ca_file);
  }
  if (!options.tls_cert_file.empty()) {
    if (!ReadFile(options.tls_cert_file, &ssl.pem_cert_chain)) {
      return invalid("tls_cert_file: cannot read " + options.tls_cert_file);
    }
    if (!ReadFile(options.tls_key_file, &ssl.pem_private_key)) {
      return invalid("tls_key_file: cannot read " + options.tls_key_file);
    }
  }
  *credentials = grpc::SslCredentials(ssl);
  if (!options.auth_token.empty()) {
    // gRPC's access-token credentials send "authorization: Bearer <token>".
    *credentials = grpc::CompositeChannelCredentials(*credentials, grpc::AccessTokenCredentials(options.auth_token));
  }
  return Status::Ok();
}

std::shared_ptr<grpc::Channel> MakeChannel(const ClientOptions& options,
                                           const std::shared_ptr<grpc::ChannelCredentials>& credentials) {
  grpc::ChannelArguments args;
  const int reconnect_max = static_cast<int>(options.reconnect_backoff_max.count());
  const int reconnect_min = reconnect_max < 100 ? reconnect_max : 100;
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, reconnect_min);
  args.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, reconnect_min);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, reconnect_max);
  args.SetMaxReceiveMessageSize(options.max_message_bytes);
  args.SetMaxSendMessageSize(options.max_message_bytes);
  if (!options.tls_server_name.empty()) args.SetSslTargetNameOverride(options.tls_server_name);
  return grpc::CreateCustomChannel(NormaliseTarget(options.target), credentials, args);
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
