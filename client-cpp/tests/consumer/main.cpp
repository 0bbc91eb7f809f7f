// Job: proves the installed package works from C++11 code: includes every
// public header, uses the helpers, and drives a client with no server
// listening (the insert stays queued and Close() reports it undelivered).
// Exits 0 on success.
#include <humem/humem.h>

#if __cplusplus != 201103L
#error "this consumer must be compiled as C++11"
#endif

#include <cstdio>
#include <memory>
#include <string>
#include <vector>

struct KeyFrame {
  unsigned long mnId;
};

#define CHECK(cond)                                          \
  do {                                                       \
    if (!(cond)) {                                           \
      std::fprintf(stderr, "consumer: failed: %s\n", #cond); \
      return 1;                                              \
    }                                                        \
  } while (0)

int main(int argc, char** argv) {
  // Helpers.
  humem::ImageCache images(2);
  const std::vector<uint8_t> pixels(16 * 16, 7);
  images.Put(1, std::make_shared<const humem::Image>(humem::Image::Raw(humem::Image::kGray8, &pixels[0], 16, 16)));
  std::shared_ptr<const humem::Image> image;
  CHECK(images.Get(1, &image) && image->width == 16);

  humem::KeyframeRegistry<KeyFrame> registry;
  KeyFrame kf = {3};
  registry.Add(kf.mnId, &kf);
  CHECK(registry.Find(3) == &kf);

  const float eigen_column_major[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 4, 5, 6, 1};
  const humem::Pose pose = humem::Pose::FromMatrixColumnMajor(eigen_column_major);
  CHECK(pose.translation.x == 4 && pose.rotation.w == 1);

  // A client with nothing listening: writes queue, Close reports them.
  humem::ClientOptions options;
  options.target = argc > 1 ? argv[1] : "127.0.0.1:1";
  options.robot_id = "consumer";
  humem::Status status;
  std::unique_ptr<humem::VprClient> client = humem::VprClient::Create(options, &status);
  CHECK(client && status.ok());
  humem::Keyframe keyframe;
  keyframe.keyframe_id = 3;
  keyframe.pose = pose;
  keyframe.features.descriptor.assign(8, 0.5f);
  CHECK(client->Insert(keyframe).state == humem::WriteState::kQueued);
  // A verdict is a write too: it queues behind the insert.
  humem::Verification verdict;
  verdict.keyframe_id = 3;
  verdict.candidate_keyframe_id = 1;
  verdict.kind = humem::VerificationKind::kLoop;
  verdict.accepted = true;
  verdict.relative = humem::RelativeTransform(pose, 1.0);
  CHECK(client->ReportVerification(verdict).state == humem::WriteState::kQueued);
  humem::QueryRequest query;
  query.frame_id = 1000;
  humem::Features features;
  features.descriptor.assign(8, 0.5f);
  query.features = features;
  const humem::Ticket ticket = client->SubmitQuery(query);
  const humem::QueryResult result = client->WaitFor(ticket, std::chrono::milliseconds(5000));
  CHECK(result.state == humem::QueryState::kFailed);
  std::printf("consumer: query while no server listens: %s\n", result.status.ToString().c_str());
  const humem::Status closed = client->Close(std::chrono::milliseconds(100));
  std::printf("consumer: close: %s\n", closed.ToString().c_str());
  CHECK(closed.code == humem::StatusCode::kAborted);
  std::printf("consumer: OK\n");
  return 0;
}
