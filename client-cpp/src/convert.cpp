// Job: the struct <-> protobuf conversions declared in convert.h.
#include "convert.h"

namespace humem::internal {

void ToProto(const Pose& pose, v1::Pose* out) {
  v1::Vec3* t = out->mutable_translation();
  t->set_x(pose.translation.x);
  t->set_y(pose.translation.y);
  t->set_z(pose.translation.z);
  v1::Quaternion* q = out->mutable_rotation();
  q->set_w(pose.rotation.w);
  q->set_x(pose.rotation.x);
  q->set_y(pose.rotation.y);
  q->set_z(pose.rotation.z);
}

Pose FromProto(const v1::Pose& pose) {
  Pose out;
  out.translation = Vec3(pose.translation().x(), pose.translation().y(), pose.translation().z());
  if (pose.has_rotation()) {
    out.rotation = Quaternion(pose.rotation().w(), pose.rotation().x(), pose.rotation().y(),
                              pose.rotation().z());
  }
  return out;
}

void ToProto(const Features& features, v1::Features* out) {
  out->mutable_global_descriptor()->Assign(features.descriptor.begin(), features.descriptor.end());
  for (const SceneClass& s : features.scene) {
    v1::SceneClass* p = out->add_scene();
    p->set_class_id(s.class_id);
    p->set_probability(s.probability);
  }
  for (const ObjectObservation& o : features.objects) {
    v1::ObjectObservation* p = out->add_objects();
    p->set_class_name(o.class_name);
    p->set_confidence(o.confidence);
    p->set_x(o.x);
    p->set_y(o.y);
    p->set_area(o.area);
    for (const TextObservation& t : o.texts) {
      v1::TextObservation* pt = p->add_texts();
      pt->set_text(t.text);
      pt->set_confidence(t.confidence);
    }
  }
}

void ToProto(const Image& image, v1::Image* out) {
  out->set_encoding(static_cast<v1::Image::Encoding>(image.encoding));
  out->set_data(image.data.data(), image.data.size());
  out->set_width(image.width);
  out->set_height(image.height);
  out->set_stride(image.stride);
}

void ToProto(const Keyframe& keyframe, const std::string& robot_id, const std::string& session_id,
             v1::Keyframe* out) {
  out->set_robot_id(robot_id);
  out->set_session_id(session_id);
  out->set_keyframe_id(keyframe.keyframe_id);
  out->set_frame_id(keyframe.frame_id);
  out->set_timestamp(keyframe.timestamp);
  out->set_map_id(keyframe.map_id);
  ToProto(keyframe.pose, out->mutable_pose());
  if (keyframe.image) {
    ToProto(*keyframe.image, out->mutable_image());
  } else {
    ToProto(keyframe.features, out->mutable_features());
  }
}

void ToProto(const QueryRequest& request, const std::string& robot_id, const std::string& session_id,
             v1::QueryRequest* out) {
  out->set_robot_id(robot_id);
  out->set_session_id(session_id);
  if (request.map_id.has_value()) out->set_map_id(request.map_id.value());
  if (request.frame_id.has_value()) out->set_frame_id(request.frame_id.value());
  if (request.keyframe_id.has_value()) out->set_keyframe_id(request.keyframe_id.value());
  if (request.image) {
    ToProto(*request.image, out->mutable_image());
  } else if (request.features.has_value()) {
    ToProto(request.features.value(), out->mutable_features());
  }
  out->mutable_predecessor_keyframe_ids()->Assign(request.predecessor_keyframe_ids.begin(),
                                                  request.predecessor_keyframe_ids.end());
  out->set_scope(static_cast<v1::Scope>(request.scope));
  for (const std::string& r : request.robot_ids) out->add_robot_ids(r);
  for (const MapRef& m : request.maps) {
    v1::MapRef* p = out->add_maps();
    p->set_robot_id(m.robot_id);
    if (m.session_id.has_value()) p->set_session_id(m.session_id.value());
    p->set_map_id(m.map_id);
  }
  if (request.min_frame_gap.has_value()) out->set_min_frame_gap(request.min_frame_gap.value());
  if (request.top_n.has_value()) out->set_top_n(request.top_n.value());
  if (request.threshold.has_value()) out->set_threshold(request.threshold.value());
  out->set_layers(static_cast<v1::Layers>(request.layers));
  out->set_kind(static_cast<v1::QueryKind>(request.kind));
}

void ToProto(const PoseUpdate& update, v1::PoseUpdate* out) {
  out->set_keyframe_id(update.keyframe_id);
  ToProto(update.pose, out->mutable_pose());
  if (update.map_id.has_value()) out->set_map_id(update.map_id.value());
}

void ToProto(const Verification& verdict, const std::string& robot_id, const std::string& session_id,
             v1::ReportVerificationRequest* out) {
  out->set_robot_id(robot_id);
  out->set_session_id(session_id);
  out->set_keyframe_id(verdict.keyframe_id);
  v1::KeyframeRef* candidate = out->mutable_candidate();
  candidate->set_robot_id(verdict.candidate_robot_id.empty() ? robot_id : verdict.candidate_robot_id);
  candidate->set_session_id(verdict.candidate_session_id.has_value() ? verdict.candidate_session_id.value()
                                                                     : session_id);
  candidate->set_keyframe_id(verdict.candidate_keyframe_id);
  out->set_kind(static_cast<v1::VerificationKind>(verdict.kind));
  out->set_outcome(verdict.accepted ? v1::VERIFICATION_OUTCOME_ACCEPTED : v1::VERIFICATION_OUTCOME_REJECTED);
  // The server ignores the transform of a rejection: do not send one.
  if (verdict.accepted && verdict.relative.has_value()) {
    v1::RelativeTransform* relative = out->mutable_relative();
    ToProto(verdict.relative.value().pose, relative->mutable_pose());
    relative->set_scale(verdict.relative.value().scale);
  }
  if (verdict.score.has_value()) out->set_score(verdict.score.value());
  out->set_inliers(verdict.inliers);
}

Candidate FromProto(const v1::Candidate& c) {
  Candidate out;
  out.robot_id = c.robot_id();
  out.session_id = c.session_id();
  out.keyframe_id = c.keyframe_id();
  out.frame_id = c.frame_id();
  out.map_id = c.map_id();
  out.timestamp = c.timestamp();
  out.pose = FromProto(c.pose());
  out.score = c.score();
  const v1::Evidence& e = c.evidence();
  Evidence& ev = out.evidence;
  ev.scene_score = e.scene_score();
  ev.descriptor_cosine = e.descriptor_cosine();
  if (e.has_scene_compatibility()) ev.scene_compatibility = e.scene_compatibility();
  ev.temporal_depth = e.temporal_depth();
  ev.object_score = e.object_score();
  ev.text_score = e.text_score();
  ev.text_distinctiveness = e.text_distinctiveness();
  ev.corroboration = e.corroboration();
  ev.verdict_penalty = e.verdict_penalty();
  ev.verdict_support = e.verdict_support();
  ev.verdict_rejections = e.verdict_rejections();
  ev.verdict_acceptances = e.verdict_acceptances();
  if (e.has_drift()) {
    DriftEnvelope d;
    d.distance = e.drift().distance();
    d.path = e.drift().path();
    d.ratio = e.drift().ratio();
    d.allowance = e.drift().allowance();
    d.penalty = e.drift().penalty();
    ev.drift = d;
  }
  for (const v1::ObjectMatch& m : e.object_matches()) {
    ObjectMatch o;
    o.query_object = m.query_object();
    o.candidate_object = m.candidate_object();
    o.class_name = m.class_name();
    o.affinity = m.affinity();
    o.spatial = m.spatial();
    ev.object_matches.push_back(o);
  }
  for (const v1::TextMatch& m : e.text_matches()) {
    TextMatch t;
    t.query_object = m.query_object();
    t.candidate_object = m.candidate_object();
    t.query_text = m.query_text();
    t.candidate_text = m.candidate_text();
    t.similarity = m.similarity();
    t.score = m.score();
    t.distinctiveness = m.distinctiveness();
    ev.text_matches.push_back(t);
  }
  return out;
}

void FromProto(const v1::QueryResponse& response, QueryResult* out) {
  out->state = response.status() == v1::QUERY_STATUS_SUPERSEDED ? QueryState::kSupersededByServer
                                                                 : QueryState::kAnswered;
  out->status = Status::Ok();
  out->candidates.clear();
  for (const v1::Candidate& c : response.candidates()) out->candidates.push_back(FromProto(c));
  out->eligible_keyframes = response.eligible_keyframes();
  out->threshold = response.threshold();
  out->operating_threshold = response.operating_threshold();
  out->used_predecessor_ids.assign(response.used_predecessor_ids().begin(),
                                   response.used_predecessor_ids().end());
  out->timings.clear();
  for (const v1::StageTiming& t : response.timings()) {
    StageTiming s;
    s.stage = t.stage();
    s.seconds = t.seconds();
    out->timings.push_back(s);
  }
}

void FromProto(const v1::StatsResponse& response, StoreStats* out) {
  out->keyframes = response.keyframes();
  out->descriptor_dim = response.descriptor_dim();
  out->maps.clear();
  for (const v1::MapStats& m : response.maps()) {
    MapStats s;
    s.robot_id = m.robot_id();
    s.session_id = m.session_id();
    s.map_id = m.map_id();
    s.keyframes = m.keyframes();
    out->maps.push_back(s);
  }
  out->disk_bytes = response.disk_bytes();
  out->format_version = response.format_version();
  out->server_version = response.server_version();
  out->verdicts = response.verdicts();
  const v1::OperatingPoint& point = response.operating_point();
  out->operating_point = OperatingPoint();
  out->operating_point.threshold = point.threshold();
  out->operating_point.configured_threshold = point.configured_threshold();
  if (point.has_estimated_precision()) out->operating_point.estimated_precision = point.estimated_precision();
  if (point.has_configured_precision())
    out->operating_point.configured_precision = point.configured_precision();
  out->operating_point.verdicts = point.verdicts();
}

}  // namespace humem::internal
