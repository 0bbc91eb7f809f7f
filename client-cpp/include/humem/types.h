// Job: the plain C++ data types of the HuMem API: keyframes, features,
// images, poses, queries and their answers, store statistics. They mirror
// proto/humem/v1/humem.proto (see it for every field's meaning and limits)
// and are converted to and from protobuf inside the library, so this header
// pulls in neither gRPC nor protobuf and compiles as C++11.
#ifndef HUMEM_TYPES_H_
#define HUMEM_TYPES_H_

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "humem/export.h"
#include "humem/optional.h"
#include "humem/status.h"

namespace humem {

// ---------------------------------------------------------------------------
// Geometry

struct Vec3 {
  double x, y, z;
  Vec3() : x(0), y(0), z(0) {}
  Vec3(double x_, double y_, double z_) : x(x_), y(y_), z(z_) {}
};

// A rotation as a quaternion (normalised by the server; zero is refused).
struct Quaternion {
  double w, x, y, z;
  Quaternion() : w(1), x(0), y(0), z(0) {}  // identity
  Quaternion(double w_, double x_, double y_, double z_) : w(w_), x(x_), y(y_), z(z_) {}
};

// A camera-to-world pose T_wc of a keyframe in its map's frame (ORB-SLAM3's
// KeyFrame::GetPoseInverse()). Default: identity.
struct HUMEM_API Pose {
  Vec3 translation;
  Quaternion rotation;

  Pose() {}
  Pose(const Vec3& t, const Quaternion& q) : translation(t), rotation(q) {}

  // From a 4x4 homogeneous matrix [R t; 0 1] of 16 values. Row-major is C's
  // `m[4][4]`; column-major is Eigen's default storage, so an ORB-SLAM3
  // pose converts as Pose::FromMatrixColumnMajor(Twc.matrix().data()).
  // Only the rotation block and translation column are read.
  static Pose FromMatrixRowMajor(const double* m16);
  static Pose FromMatrixRowMajor(const float* m16);
  static Pose FromMatrixColumnMajor(const double* m16);
  static Pose FromMatrixColumnMajor(const float* m16);

  // The pose as a row-major 4x4 matrix (the quaternion normalised first).
  void ToMatrixRowMajor(double* m16) const;
};

// ---------------------------------------------------------------------------
// What a keyframe shows

struct SceneClass {
  uint32_t class_id;
  float probability;
  SceneClass() : class_id(0), probability(0) {}
  SceneClass(uint32_t id, float p) : class_id(id), probability(p) {}
};

struct TextObservation {
  std::string text;
  float confidence;
  TextObservation() : confidence(0) {}
  TextObservation(const std::string& t, float c) : text(t), confidence(c) {}
};

// A detected object: class, confidence, centroid (x, y in [0, 1], origin
// top-left), area fraction, and text read on it.
struct ObjectObservation {
  std::string class_name;
  float confidence;
  float x, y;
  float area;
  std::vector<TextObservation> texts;
  ObjectObservation() : confidence(0), x(0), y(0), area(0) {}
};

// Precomputed perception output: a global descriptor (required for
// keyframes), optional scene classes and objects.
struct Features {
  std::vector<float> descriptor;
  std::vector<SceneClass> scene;
  std::vector<ObjectObservation> objects;
};

// A camera image for the server's models: an encoded file (JPEG/PNG) or raw
// 8-bit pixels with their size.
struct Image {
  enum Encoding {
    kUnspecified = 0,  // JPEG or PNG, recognised from the bytes
    kJpeg = 1,
    kPng = 2,
    kGray8 = 3,  // one byte per pixel (ORB-SLAM3's grayscale frames)
    kRgb8 = 4,
    kBgr8 = 5,  // OpenCV's default order
  };
  Encoding encoding;
  std::vector<uint8_t> data;
  uint32_t width;   // raw encodings only
  uint32_t height;  // raw encodings only
  uint32_t stride;  // raw encodings only; 0 = tightly packed

  Image() : encoding(kUnspecified), width(0), height(0), stride(0) {}

  // Copies raw pixels (rows `stride` bytes apart, 0 = packed) into a tightly
  // packed image, e.g. Image::Raw(Image::kGray8, im.data, im.cols, im.rows,
  // im.step) for a cv::Mat.
  static Image Raw(Encoding encoding, const uint8_t* pixels, uint32_t width, uint32_t height,
                   size_t stride = 0) {
    Image image;
    image.encoding = encoding;
    image.width = width;
    image.height = height;
    const size_t channels = encoding == kGray8 ? 1 : 3;
    const size_t row = static_cast<size_t>(width) * channels;
    const size_t step = stride == 0 ? row : stride;
    image.data.resize(row * height);
    for (uint32_t y = 0; y < height; ++y) {
      const uint8_t* src = pixels + static_cast<size_t>(y) * step;
      std::copy(src, src + row, image.data.begin() + static_cast<std::ptrdiff_t>(y * row));
    }
    return image;
  }
};

// A keyframe as sent by the SLAM system. The robot and session come from
// the client (ClientOptions / VprClient::SetSession).
struct Keyframe {
  uint64_t keyframe_id;  // KeyFrame::mnId
  uint64_t frame_id;     // KeyFrame::mnFrameId
  uint64_t map_id;       // Map::GetId()
  double timestamp;      // seconds
  Pose pose;             // T_wc
  // Content: if `image` is set the server computes the features from it
  // (perception must be enabled there) and `features` is ignored;
  // otherwise `features` is sent.
  Features features;
  std::shared_ptr<const Image> image;

  Keyframe() : keyframe_id(0), frame_id(0), map_id(0), timestamp(0) {}
};

// ---------------------------------------------------------------------------
// Queries

enum class QueryKind : int {
  kLoopClosure = 1,     // loop closure / map merge for a new keyframe
  kRelocalisation = 2,  // relocalisation while tracking is lost
};

enum class Scope : int {
  kUnspecified = 0,  // server default: all maps
  kSameMap = 1,
  kOtherMaps = 2,
  kAllMaps = 3,
  kListed = 4,  // only `robot_ids` and `maps`
};

enum class Layers : int {
  kUnspecified = 0,  // server default: full
  kScal = 1,
  kScalOsrl = 2,
  kScalOgtl = 3,
  kFull = 4,
};

struct MapRef {
  std::string robot_id;
  Optional<std::string> session_id;  // unset: the map id in every session
  uint64_t map_id;
  MapRef() : map_id(0) {}
};

// A query. Unset optional fields take the server's defaults.
struct QueryRequest {
  QueryKind kind;
  Optional<uint64_t> map_id;       // required for kSameMap / kOtherMaps
  Optional<uint64_t> frame_id;     // required unless keyframe_id is stored
  Optional<uint64_t> keyframe_id;  // when the query is a keyframe
  // Content: `image` if set, else `features` if set, else none (then
  // `keyframe_id` must name a stored keyframe).
  Optional<Features> features;
  std::shared_ptr<const Image> image;
  std::vector<uint64_t> predecessor_keyframe_ids;  // most recent first
  Scope scope;
  std::vector<std::string> robot_ids;  // kListed
  std::vector<MapRef> maps;            // kListed
  Optional<uint64_t> min_frame_gap;
  Optional<uint32_t> top_n;
  Optional<float> threshold;
  Layers layers;
  // Client-side only (not sent): hold the query back until every write this
  // client queued before SubmitQuery has been applied by the server or has
  // failed for good, then send it. For a query by `keyframe_id` alone right
  // after that keyframe's Insert: the server then holds the keyframe (unless
  // the insert failed: NOT_FOUND). Latest wins as for any query: while it
  // is pending a newer submission supersedes it; once the kind's lane takes
  // it, it holds the lane while it waits for the writes (its ticket stays
  // kQueued until sent), and newer queries wait behind it as behind a query
  // in flight. `query_timeout` counts from when the lane takes it: writes
  // not applied by then fail it with DEADLINE_EXCEEDED, unsent. No polling:
  // the query thread sleeps until the writer reports progress.
  bool after_queued_writes;

  QueryRequest()
      : kind(QueryKind::kLoopClosure), scope(Scope::kUnspecified), layers(Layers::kUnspecified),
        after_queued_writes(false) {}
};

struct ObjectMatch {
  uint32_t query_object, candidate_object;
  std::string class_name;
  float affinity, spatial;
  ObjectMatch() : query_object(0), candidate_object(0), affinity(0), spatial(0) {}
};

struct TextMatch {
  uint32_t query_object, candidate_object;
  std::string query_text, candidate_text;
  float similarity, score, distinctiveness;
  TextMatch() : query_object(0), candidate_object(0), similarity(0), score(0), distinctiveness(0) {}
};

// Where a candidate of the query's own map lies against the map's drift
// (map units): beyond allowance its score lost penalty, up to 0.1 at twice
// the allowed ratio (see the proto's DriftEnvelope).
struct DriftEnvelope {
  double distance, path, ratio, allowance;
  float penalty;
  DriftEnvelope() : distance(0), path(0), ratio(0), allowance(0), penalty(0) {}
};

// Why a candidate was proposed (see the proto's Evidence).
struct Evidence {
  float scene_score;
  float descriptor_cosine;
  Optional<float> scene_compatibility;
  uint32_t temporal_depth;
  float object_score;
  float text_score;
  float text_distinctiveness;
  float corroboration;
  std::vector<ObjectMatch> object_matches;
  std::vector<TextMatch> text_matches;
  // What earlier verdicts (VprClient::ReportVerification) did to this
  // candidate: P, the look-alike penalty, and V, the verified-place support,
  // both in [0, 1], and how many rejections and acceptances applied.
  float verdict_penalty;
  float verdict_support;
  uint32_t verdict_rejections;
  uint32_t verdict_acceptances;
  // Set for a candidate of the query's own map when the query is a stored
  // keyframe: its distance from the query, the path between them, r, the
  // allowance and the penalty.
  Optional<DriftEnvelope> drift;
  Evidence()
      : scene_score(0), descriptor_cosine(0), temporal_depth(0), object_score(0), text_score(0),
        text_distinctiveness(0), corroboration(0), verdict_penalty(0), verdict_support(0),
        verdict_rejections(0), verdict_acceptances(0) {}
};

// One proposed place, best first in a result.
struct Candidate {
  std::string robot_id;
  std::string session_id;
  uint64_t keyframe_id;
  uint64_t frame_id;
  uint64_t map_id;
  double timestamp;
  Pose pose;
  float score;  // Λ in [0, 1]
  Evidence evidence;
  Candidate() : keyframe_id(0), frame_id(0), map_id(0), timestamp(0), score(0) {}
};

struct StageTiming {
  std::string stage;
  double seconds;
  StageTiming() : seconds(0) {}
};

// Identifies one submitted query. 0 is never issued.
typedef uint64_t Ticket;

enum class QueryState : int {
  kQueued = 1,     // waiting in the client's pending slot (not resolved)
  kInFlight = 2,   // sent, no answer yet (not resolved)
  kAnswered = 3,   // ranked: `candidates` holds the answer (possibly empty)
  kSuperseded = 4,  // a newer SubmitQuery of the same kind replaced it in
                    // the client before it was sent
  kSupersededByServer = 5,  // sent, but the server answered
                            // QUERY_STATUS_SUPERSEDED (a newer query of the
                            // same robot, session and kind took its place)
  kFailed = 6,      // the RPC failed; `status` says why
  kUnknownTicket = 7,  // never issued, or its result is no longer kept
};

inline const char* QueryStateName(QueryState s) {
  switch (s) {
    case QueryState::kQueued: return "queued";
    case QueryState::kInFlight: return "in flight";
    case QueryState::kAnswered: return "answered";
    case QueryState::kSuperseded: return "superseded";
    case QueryState::kSupersededByServer: return "superseded by server";
    case QueryState::kFailed: return "failed";
    case QueryState::kUnknownTicket: return "unknown ticket";
  }
  return "?";
}

// The state and, once answered, the answer of one ticket.
struct QueryResult {
  Ticket ticket;
  QueryKind kind;
  QueryState state;
  // OK when answered or superseded; the error when failed; from WaitFor,
  // DEADLINE_EXCEEDED while the ticket is still queued or in flight.
  Status status;
  std::vector<Candidate> candidates;  // best first
  uint64_t eligible_keyframes;
  std::vector<uint64_t> used_predecessor_ids;
  std::vector<StageTiming> timings;
  double round_trip_seconds;  // from sending to the reply (0 if not sent)
  // The threshold applied to Candidate::score, and the store's operating
  // point when the query ran (what a query naming no threshold gets: the
  // configured one, or the one SLAM's verdicts adapted). 0 until answered.
  float threshold;
  float operating_threshold;

  QueryResult()
      : ticket(0), kind(QueryKind::kLoopClosure), state(QueryState::kQueued), eligible_keyframes(0),
        round_trip_seconds(0), threshold(0), operating_threshold(0) {}

  // True once the ticket will not change any more.
  bool resolved() const { return state != QueryState::kQueued && state != QueryState::kInFlight; }
};

// ---------------------------------------------------------------------------
// Writes and store statistics

struct PoseUpdate {
  uint64_t keyframe_id;
  Pose pose;
  Optional<uint64_t> map_id;  // set when a merge moved the keyframe
  PoseUpdate() : keyframe_id(0) {}
};

// Which geometric check the SLAM system ran on a candidate.
enum class VerificationKind : int {
  kLoop = 1,            // loop closure within one map (Sim3 / SE3 + covisibility check)
  kMerge = 2,           // map merge between two maps
  kRelocalisation = 3,  // relocalisation of a lost frame (PnP + pose optimisation)
};

// A similarity transform: rotation, translation and scale (1 for SE(3)).
struct RelativeTransform {
  Pose pose;
  double scale;  // 0 means 1
  RelativeTransform() : scale(1) {}
  RelativeTransform(const Pose& p, double s) : pose(p), scale(s) {}
};

// The SLAM system's geometric verdict on a candidate HuMem proposed, for
// VprClient::ReportVerification. The query keyframe is one of the client's
// robot and session; both it and the candidate must be stored.
struct Verification {
  // The query keyframe (the keyframe or, for relocalisation, the keyframe
  // standing in for the lost frame). Must be stored.
  uint64_t keyframe_id;
  // The candidate as HuMem returned it (Candidate::robot_id, session_id,
  // keyframe_id). An empty robot id means the client's robot; an unset
  // session id means the client's current session.
  std::string candidate_robot_id;
  Optional<std::string> candidate_session_id;
  uint64_t candidate_keyframe_id;
  VerificationKind kind;
  // True: the SLAM system closed the loop, merged or relocalised with it.
  bool accepted;
  // When accepted: T_qc, the candidate camera in the query camera's frame
  // (the scale of a monocular Sim3). Not sent when rejected.
  Optional<RelativeTransform> relative;
  // Candidate::score HuMem gave it, if known.
  Optional<float> score;
  // Inliers of the geometric check (0: unknown).
  uint32_t inliers;

  Verification()
      : keyframe_id(0), candidate_keyframe_id(0), kind(VerificationKind::kLoop), accepted(false), inliers(0) {}

  // A verdict on candidate `c` of the query keyframe `query_keyframe_id`
  // (candidate ids and score copied from `c`).
  static Verification Of(uint64_t query_keyframe_id, const Candidate& c, VerificationKind kind, bool accepted) {
    Verification v;
    v.keyframe_id = query_keyframe_id;
    v.candidate_robot_id = c.robot_id;
    v.candidate_session_id = c.session_id;
    v.candidate_keyframe_id = c.keyframe_id;
    v.kind = kind;
    v.accepted = accepted;
    v.score = c.score;
    return v;
  }
};

struct MapStats {
  std::string robot_id;
  std::string session_id;
  uint64_t map_id;
  uint64_t keyframes;
  MapStats() : map_id(0), keyframes(0) {}
};

// The store's operating point (StatsResponse.operating_point).
struct OperatingPoint {
  float threshold;             // in force
  float configured_threshold;  // as configured
  // Estimated precision of the candidates sent at each, from the verdicts;
  // unset while too few verdicts exist.
  Optional<double> estimated_precision;
  Optional<double> configured_precision;
  uint64_t verdicts;  // scored verdicts above the configured threshold
  OperatingPoint() : threshold(0), configured_threshold(0), verdicts(0) {}
};

struct StoreStats {
  uint64_t keyframes;
  uint32_t descriptor_dim;  // 0 until fixed
  std::vector<MapStats> maps;
  uint64_t disk_bytes;
  uint32_t format_version;
  std::string server_version;
  uint64_t verdicts;  // verification verdicts stored (ReportVerification)
  OperatingPoint operating_point;
  StoreStats() : keyframes(0), descriptor_dim(0), disk_bytes(0), format_version(0), verdicts(0) {}

  // Keyframes stored for one robot/session/map (0 if none).
  uint64_t KeyframesIn(const std::string& robot, const std::string& session, uint64_t map) const {
    for (size_t i = 0; i < maps.size(); ++i) {
      if (maps[i].robot_id == robot && maps[i].session_id == session && maps[i].map_id == map) {
        return maps[i].keyframes;
      }
    }
    return 0;
  }
};

}  // namespace humem

#endif  // HUMEM_TYPES_H_
