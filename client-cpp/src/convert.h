// Job: conversions between the public plain structs (humem/types.h) and the
// generated protobuf messages of proto/humem/v1/humem.proto. The only place
// that knows both; no gRPC here.
#ifndef HUMEM_SRC_CONVERT_H_
#define HUMEM_SRC_CONVERT_H_

#include <string>

#include "humem/types.h"
#include "humem/v1/humem.pb.h"

namespace humem::internal {

void ToProto(const Pose& pose, v1::Pose* out);
Pose FromProto(const v1::Pose& pose);

void ToProto(const Features& features, v1::Features* out);
void ToProto(const Image& image, v1::Image* out);

// The keyframe, made for `robot_id`/`session_id`.
void ToProto(const Keyframe& keyframe, const std::string& robot_id, const std::string& session_id,
             v1::Keyframe* out);

// The query, asked by `robot_id`/`session_id`.
void ToProto(const QueryRequest& request, const std::string& robot_id, const std::string& session_id,
             v1::QueryRequest* out);

void ToProto(const PoseUpdate& update, v1::PoseUpdate* out);

// The verdict, reported by `robot_id`/`session_id` (the query keyframe's;
// also the candidate's when the verdict leaves them empty/unset).
void ToProto(const Verification& verdict, const std::string& robot_id, const std::string& session_id,
             v1::ReportVerificationRequest* out);

Candidate FromProto(const v1::Candidate& candidate);

// Fills the answer part of *out and sets its state: kSupersededByServer if
// the server answered QUERY_STATUS_SUPERSEDED, else kAnswered.
void FromProto(const v1::QueryResponse& response, QueryResult* out);

void FromProto(const v1::StatsResponse& response, StoreStats* out);

}  // namespace humem::internal

#endif  // HUMEM_SRC_CONVERT_H_
