// Job: test data and shortcuts for the server tests: reproducible random
// descriptors, keyframes made from them, queries near them, and a client
// connected to a test server.
#ifndef HUMEM_TESTS_TEST_DATA_H_
#define HUMEM_TESTS_TEST_DATA_H_

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "humem/humem.h"
#include "humem_server.h"

namespace humem_test {

constexpr size_t kDim = 64;
// Queries use a frame id far from every keyframe's, so the server's minimum
// frame gap (100) never hides a candidate of the querying session.
constexpr uint64_t kQueryFrame = 1000000;

std::vector<float> RandomDescriptor(uint32_t seed);
// `base` plus small noise: cosine to `base` above 0.99.
std::vector<float> Near(const std::vector<float>& base, uint32_t seed);

// Keyframe `id` in `map`, frame id 10*id, at (id, 0, 0), descriptor from seed `id`.
humem::Keyframe MakeKeyframe(uint64_t id, uint64_t map);

// A loop-closure query (all maps) with `descriptor`.
humem::QueryRequest QueryWith(const std::vector<float>& descriptor,
                              humem::QueryKind kind = humem::QueryKind::kLoopClosure);

// A client of `server` for robot "robot" and `session`, with short back-offs.
std::unique_ptr<humem::VprClient> Connect(const HumemServer& server, const std::string& session = "s1",
                                          humem::ClientOptions options = humem::ClientOptions());

std::chrono::milliseconds Ms(long long n);

}  // namespace humem_test

#endif  // HUMEM_TESTS_TEST_DATA_H_
