// Job: the test data helpers declared in test_data.h.
#include "test_data.h"

#include <random>
#include <stdexcept>

namespace humem_test {

std::vector<float> RandomDescriptor(uint32_t seed) {
  std::mt19937 rng(seed * 7919u + 17u);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  std::vector<float> d(kDim);
  for (float& v : d) v = normal(rng);
  return d;
}

std::vector<float> Near(const std::vector<float>& base, uint32_t seed) {
  std::mt19937 rng(seed + 1000003u);
  std::normal_distribution<float> normal(0.0f, 0.05f);
  std::vector<float> d = base;
  for (float& v : d) v += normal(rng);
  return d;
}

humem::Keyframe MakeKeyframe(uint64_t id, uint64_t map) {
  humem::Keyframe kf;
  kf.keyframe_id = id;
  kf.frame_id = 10 * id;
  kf.map_id = map;
  kf.timestamp = 0.1 * static_cast<double>(id);
  kf.pose.translation = humem::Vec3(static_cast<double>(id), 0, 0);
  kf.features.descriptor = RandomDescriptor(static_cast<uint32_t>(id));
  return kf;
}

humem::QueryRequest QueryWith(const std::vector<float>& descriptor, humem::QueryKind kind) {
  humem::QueryRequest q;
  q.kind = kind;
  q.frame_id = kQueryFrame;
  humem::Features f;
  f.descriptor = descriptor;
  q.features = f;
  return q;
}

std::unique_ptr<humem::VprClient> Connect(const HumemServer& server, const std::string& session,
                                          humem::ClientOptions options) {
  server.Connect(&options);
  options.robot_id = "robot";
  options.session_id = session;
  options.retry_backoff_initial = Ms(20);
  options.retry_backoff_max = Ms(200);
  options.reconnect_backoff_max = Ms(200);
  options.write_attempt_timeout = Ms(2000);
  humem::Status status;
  std::unique_ptr<humem::VprClient> client = humem::VprClient::Create(options, &status);
  if (!client) throw std::runtime_error("VprClient::Create: " + status.ToString());
  return client;
}

std::chrono::milliseconds Ms(long long n) { return std::chrono::milliseconds(n); }

}  // namespace humem_test
