// Job: unit tests of the struct <-> protobuf conversions (src/convert.h)
// and of Pose's matrix conversions, including how a server-side
// QUERY_STATUS_SUPERSEDED surfaces in a QueryResult.
#include "convert.h"

#include <gtest/gtest.h>

#include <cmath>

namespace {

using namespace humem;
using namespace humem::internal;

TEST(Pose, MatrixRoundTripInBothStorageOrders) {
  // 90 degrees about z, then translated.
  const double row_major[16] = {0, -1, 0, 1,  //
                                1, 0,  0, 2,  //
                                0, 0,  1, 3,  //
                                0, 0,  0, 1};
  double column_major[16];
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) column_major[c * 4 + r] = row_major[r * 4 + c];
  const Pose a = Pose::FromMatrixRowMajor(row_major);
  const Pose b = Pose::FromMatrixColumnMajor(column_major);
  const double h = std::sqrt(0.5);
  for (const Pose& p : {a, b}) {
    EXPECT_NEAR(p.rotation.w, h, 1e-12);
    EXPECT_NEAR(p.rotation.x, 0, 1e-12);
    EXPECT_NEAR(p.rotation.y, 0, 1e-12);
    EXPECT_NEAR(p.rotation.z, h, 1e-12);
    EXPECT_DOUBLE_EQ(p.translation.x, 1);
    EXPECT_DOUBLE_EQ(p.translation.y, 2);
    EXPECT_DOUBLE_EQ(p.translation.z, 3);
  }
  double back[16];
  a.ToMatrixRowMajor(back);
  for (int i = 0; i < 16; ++i) EXPECT_NEAR(back[i], row_major[i], 1e-12) << i;
}

TEST(Pose, EveryRotationBranchRoundTrips) {
  // Rotations of 180 degrees about x, y and z take the non-trace branches.
  const Quaternion qs[] = {Quaternion(0, 1, 0, 0), Quaternion(0, 0, 1, 0), Quaternion(0, 0, 0, 1),
                           Quaternion(0.3, -0.5, 0.7, 0.1)};
  for (const Quaternion& q : qs) {
    double m[16];
    Pose(Vec3(4, 5, 6), q).ToMatrixRowMajor(m);
    float mf[16];
    for (int i = 0; i < 16; ++i) mf[i] = static_cast<float>(m[i]);
    const Pose p = Pose::FromMatrixRowMajor(mf);
    double again[16];
    p.ToMatrixRowMajor(again);
    for (int i = 0; i < 16; ++i) EXPECT_NEAR(again[i], m[i], 1e-6) << i;
  }
}

TEST(Convert, KeyframeCarriesIdsEvenWhenZeroAndPrefersTheImage) {
  Keyframe kf;
  kf.keyframe_id = 0;
  kf.frame_id = 0;
  kf.map_id = 0;
  kf.timestamp = 1.5;
  kf.pose = Pose(Vec3(1, 2, 3), Quaternion(0, 0, 0, 1));
  kf.features.descriptor = {0.5f, 0.25f};
  kf.features.scene.push_back(SceneClass(7, 0.5f));
  ObjectObservation o;
  o.class_name = "sign";
  o.confidence = 0.9f;
  o.x = 0.1f;
  o.y = 0.2f;
  o.area = 0.05f;
  o.texts.push_back(TextObservation("EXIT 12", 0.8f));
  kf.features.objects.push_back(o);
  v1::Keyframe p;
  ToProto(kf, "robot", "s", &p);
  EXPECT_EQ(p.robot_id(), "robot");
  EXPECT_EQ(p.session_id(), "s");
  EXPECT_TRUE(p.has_keyframe_id());
  EXPECT_TRUE(p.has_frame_id());
  EXPECT_TRUE(p.has_map_id());
  EXPECT_EQ(p.timestamp(), 1.5);
  EXPECT_EQ(p.pose().translation().y(), 2);
  EXPECT_EQ(p.pose().rotation().z(), 1);
  ASSERT_TRUE(p.has_features());
  EXPECT_EQ(p.features().global_descriptor_size(), 2);
  EXPECT_EQ(p.features().scene(0).class_id(), 7u);
  EXPECT_EQ(p.features().objects(0).texts(0).text(), "EXIT 12");
  EXPECT_FLOAT_EQ(p.features().objects(0).area(), 0.05f);

  Image image;
  image.encoding = Image::kGray8;
  image.data.assign(16 * 16, 9);
  image.width = 16;
  image.height = 16;
  kf.image = std::make_shared<const Image>(image);
  v1::Keyframe with_image;
  ToProto(kf, "robot", "s", &with_image);
  ASSERT_TRUE(with_image.has_image());
  EXPECT_FALSE(with_image.has_features());
  EXPECT_EQ(with_image.image().encoding(), v1::Image::ENCODING_GRAY8);
  EXPECT_EQ(with_image.image().data().size(), 256u);
  EXPECT_EQ(with_image.image().width(), 16u);
}

TEST(Convert, QuerySetsOnlyTheOptionalFieldsThatAreSet) {
  QueryRequest q;
  v1::QueryRequest unset;
  ToProto(q, "r", "s", &unset);
  EXPECT_FALSE(unset.has_map_id());
  EXPECT_FALSE(unset.has_frame_id());
  EXPECT_FALSE(unset.has_keyframe_id());
  EXPECT_FALSE(unset.has_min_frame_gap());
  EXPECT_FALSE(unset.has_top_n());
  EXPECT_FALSE(unset.has_threshold());
  EXPECT_EQ(unset.content_case(), v1::QueryRequest::CONTENT_NOT_SET);
  EXPECT_EQ(unset.kind(), v1::QUERY_KIND_LOOP_CLOSURE);

  q.kind = QueryKind::kRelocalisation;
  q.map_id = 0;
  q.frame_id = 12;
  q.keyframe_id = 3;
  q.min_frame_gap = 0;
  q.top_n = 10;
  q.threshold = 0.5f;
  q.scope = Scope::kListed;
  q.layers = Layers::kScalOsrl;
  q.robot_ids.push_back("other");
  MapRef m;
  m.robot_id = "other";
  m.map_id = 4;
  q.maps.push_back(m);
  q.predecessor_keyframe_ids = {2, 1};
  Features f;
  f.descriptor = {1, 2, 3};
  q.features = f;
  v1::QueryRequest set;
  ToProto(q, "r", "s", &set);
  EXPECT_TRUE(set.has_map_id());
  EXPECT_EQ(set.map_id(), 0u);
  EXPECT_EQ(set.frame_id(), 12u);
  EXPECT_EQ(set.keyframe_id(), 3u);
  EXPECT_TRUE(set.has_min_frame_gap());
  EXPECT_EQ(set.min_frame_gap(), 0u);
  EXPECT_EQ(set.top_n(), 10u);
  EXPECT_FLOAT_EQ(set.threshold(), 0.5f);
  EXPECT_EQ(set.scope(), v1::SCOPE_LISTED);
  EXPECT_EQ(set.layers(), v1::LAYERS_SCAL_OSRL);
  EXPECT_EQ(set.kind(), v1::QUERY_KIND_RELOCALISATION);
  EXPECT_EQ(set.robot_ids(0), "other");
  EXPECT_FALSE(set.maps(0).has_session_id());
  EXPECT_EQ(set.maps(0).map_id(), 4u);
  EXPECT_EQ(set.predecessor_keyframe_ids(0), 2u);
  EXPECT_EQ(set.features().global_descriptor_size(), 3);
}

TEST(Convert, ServerSupersededAnswersSurfaceAsSupersededByServer) {
  v1::QueryResponse response;
  response.set_status(v1::QUERY_STATUS_SUPERSEDED);
  QueryResult result;
  result.state = QueryState::kInFlight;
  FromProto(response, &result);
  EXPECT_EQ(result.state, QueryState::kSupersededByServer);
  EXPECT_TRUE(result.status.ok());
  EXPECT_TRUE(result.resolved());
  EXPECT_TRUE(result.candidates.empty());
}

TEST(Convert, AnsweredQueriesCarryCandidatesAndEvidence) {
  v1::QueryResponse response;
  response.set_status(v1::QUERY_STATUS_ANSWERED);
  response.set_eligible_keyframes(40);
  response.set_threshold(0.25f);
  response.set_operating_threshold(0.41f);
  response.add_used_predecessor_ids(8);
  v1::StageTiming* t = response.add_timings();
  t->set_stage("scal");
  t->set_seconds(0.002);
  for (int i = 0; i < 2; ++i) {
    v1::Candidate* c = response.add_candidates();
    c->set_robot_id("r");
    c->set_session_id("s");
    c->set_keyframe_id(10 + i);
    c->set_frame_id(100);
    c->set_map_id(2);
    c->set_score(0.9f - 0.1f * i);
    c->mutable_pose()->mutable_translation()->set_x(5);
    c->mutable_pose()->mutable_rotation()->set_w(1);
    c->mutable_evidence()->set_scene_score(0.8f);
    if (i == 0) c->mutable_evidence()->set_scene_compatibility(0.7f);
    v1::TextMatch* m = c->mutable_evidence()->add_text_matches();
    m->set_query_text("A1");
    m->set_candidate_text("A1");
  }
  QueryResult result;
  FromProto(response, &result);
  EXPECT_EQ(result.state, QueryState::kAnswered);
  ASSERT_EQ(result.candidates.size(), 2u);
  EXPECT_EQ(result.candidates[0].keyframe_id, 10u);
  EXPECT_FLOAT_EQ(result.candidates[1].score, 0.8f);
  EXPECT_EQ(result.candidates[0].pose.translation.x, 5);
  EXPECT_TRUE(result.candidates[0].evidence.scene_compatibility.has_value());
  EXPECT_FLOAT_EQ(result.candidates[0].evidence.scene_compatibility.value(), 0.7f);
  EXPECT_FALSE(result.candidates[1].evidence.scene_compatibility.has_value());
  EXPECT_EQ(result.candidates[1].evidence.text_matches[0].candidate_text, "A1");
  EXPECT_EQ(result.eligible_keyframes, 40u);
  EXPECT_FLOAT_EQ(result.threshold, 0.25f);
  EXPECT_FLOAT_EQ(result.operating_threshold, 0.41f);
  EXPECT_EQ(result.used_predecessor_ids, std::vector<uint64_t>{8});
  ASSERT_EQ(result.timings.size(), 1u);
  EXPECT_EQ(result.timings[0].stage, "scal");
}

TEST(Convert, StatsPerMap) {
  v1::StatsResponse response;
  response.set_keyframes(3);
  response.set_descriptor_dim(64);
  v1::MapStats* m = response.add_maps();
  m->set_robot_id("r");
  m->set_session_id("s");
  m->set_map_id(1);
  m->set_keyframes(3);
  response.set_server_version("1.2.3");
  response.set_verdicts(4);
  v1::OperatingPoint* point = response.mutable_operating_point();
  point->set_threshold(0.42f);
  point->set_configured_threshold(0.36f);
  point->set_estimated_precision(0.91);
  point->set_verdicts(35);
  StoreStats stats;
  FromProto(response, &stats);
  EXPECT_FLOAT_EQ(stats.operating_point.threshold, 0.42f);
  EXPECT_FLOAT_EQ(stats.operating_point.configured_threshold, 0.36f);
  ASSERT_TRUE(stats.operating_point.estimated_precision.has_value());
  EXPECT_DOUBLE_EQ(stats.operating_point.estimated_precision.value(), 0.91);
  EXPECT_FALSE(stats.operating_point.configured_precision.has_value());
  EXPECT_EQ(stats.operating_point.verdicts, 35u);
  EXPECT_EQ(stats.keyframes, 3u);
  EXPECT_EQ(stats.descriptor_dim, 64u);
  EXPECT_EQ(stats.KeyframesIn("r", "s", 1), 3u);
  EXPECT_EQ(stats.KeyframesIn("r", "s", 2), 0u);
  EXPECT_EQ(stats.server_version, "1.2.3");
  EXPECT_EQ(stats.verdicts, 4u);
}

TEST(Convert, AcceptedVerdictCarriesItsTransformScoreAndCandidate) {
  Candidate c;
  c.robot_id = "other-robot";
  c.session_id = "";  // an empty session id is a session id, not "the client's"
  c.keyframe_id = 0;  // id 0 is a keyframe id, sent as set
  c.score = 0.42f;
  Verification v = Verification::Of(7, c, VerificationKind::kMerge, true);
  v.relative = RelativeTransform(Pose(Vec3(1, 2, 3), Quaternion(0, 0, 0, 1)), 0.5);
  v.inliers = 31;
  v1::ReportVerificationRequest p;
  ToProto(v, "robot", "s1", &p);
  EXPECT_EQ(p.robot_id(), "robot");
  EXPECT_EQ(p.session_id(), "s1");
  ASSERT_TRUE(p.has_keyframe_id());
  EXPECT_EQ(p.keyframe_id(), 7u);
  ASSERT_TRUE(p.has_candidate());
  EXPECT_EQ(p.candidate().robot_id(), "other-robot");
  EXPECT_EQ(p.candidate().session_id(), "");
  ASSERT_TRUE(p.candidate().has_keyframe_id());
  EXPECT_EQ(p.candidate().keyframe_id(), 0u);
  EXPECT_EQ(p.kind(), v1::VERIFICATION_KIND_MERGE);
  EXPECT_EQ(p.outcome(), v1::VERIFICATION_OUTCOME_ACCEPTED);
  ASSERT_TRUE(p.has_relative());
  EXPECT_DOUBLE_EQ(p.relative().scale(), 0.5);
  EXPECT_DOUBLE_EQ(p.relative().pose().translation().y(), 2);
  EXPECT_DOUBLE_EQ(p.relative().pose().rotation().z(), 1);
  ASSERT_TRUE(p.has_score());
  EXPECT_FLOAT_EQ(p.score(), 0.42f);
  EXPECT_EQ(p.inliers(), 31u);
}

TEST(Convert, RejectedVerdictDefaultsToTheClientsIdsAndSendsNoTransform) {
  Verification v;
  v.keyframe_id = 12;
  v.candidate_keyframe_id = 3;
  v.kind = VerificationKind::kRelocalisation;
  v.accepted = false;
  v.relative = RelativeTransform();  // ignored for a rejection
  v1::ReportVerificationRequest p;
  ToProto(v, "robot", "s1", &p);
  EXPECT_EQ(p.candidate().robot_id(), "robot");
  EXPECT_EQ(p.candidate().session_id(), "s1");
  EXPECT_EQ(p.candidate().keyframe_id(), 3u);
  EXPECT_EQ(p.kind(), v1::VERIFICATION_KIND_RELOCALISATION);
  EXPECT_EQ(p.outcome(), v1::VERIFICATION_OUTCOME_REJECTED);
  EXPECT_FALSE(p.has_relative());
  EXPECT_FALSE(p.has_score());
  EXPECT_EQ(p.inliers(), 0u);
  // The public enum values are the proto's.
  EXPECT_EQ(static_cast<int>(VerificationKind::kLoop), v1::VERIFICATION_KIND_LOOP);
}

TEST(Convert, EvidenceCarriesTheVerdictTerms) {
  v1::Candidate c;
  v1::Evidence* e = c.mutable_evidence();
  e->set_verdict_penalty(0.25f);
  e->set_verdict_support(0.5f);
  e->set_verdict_rejections(2);
  e->set_verdict_acceptances(1);
  const Candidate out = FromProto(c);
  EXPECT_FLOAT_EQ(out.evidence.verdict_penalty, 0.25f);
  EXPECT_FLOAT_EQ(out.evidence.verdict_support, 0.5f);
  EXPECT_EQ(out.evidence.verdict_rejections, 2u);
  EXPECT_EQ(out.evidence.verdict_acceptances, 1u);
  EXPECT_FALSE(out.evidence.drift.has_value());
}

TEST(Convert, EvidenceCarriesTheDriftEnvelope) {
  v1::Candidate c;
  v1::DriftEnvelope* d = c.mutable_evidence()->mutable_drift();
  d->set_distance(3.0);
  d->set_path(213.0);
  d->set_ratio(3.0 / 213.0);
  d->set_allowance(25.8);
  d->set_penalty(0.05f);
  const Candidate out = FromProto(c);
  ASSERT_TRUE(out.evidence.drift.has_value());
  EXPECT_DOUBLE_EQ(out.evidence.drift.value().distance, 3.0);
  EXPECT_DOUBLE_EQ(out.evidence.drift.value().path, 213.0);
  EXPECT_DOUBLE_EQ(out.evidence.drift.value().ratio, 3.0 / 213.0);
  EXPECT_DOUBLE_EQ(out.evidence.drift.value().allowance, 25.8);
  EXPECT_FLOAT_EQ(out.evidence.drift.value().penalty, 0.05f);
}

}  // namespace
