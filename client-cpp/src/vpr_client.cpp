// Job: humem::VprClient's facade: validates options, owns the channel, the
// ordered writer, the two query lanes and the ticket board, turns public
// calls into queued operations, and closes everything in order.
#include "humem/vpr_client.h"

#include <algorithm>
#include <atomic>
#include <future>
#include <mutex>
#include <string>
#include <utility>

#include "convert.h"
#include "query_lane.h"
#include "result_board.h"
#include "rpc.h"
#include "writer.h"

namespace humem {

using internal::Clock;

namespace {

Status CheckOptions(const ClientOptions& o) {
  auto invalid = [](const std::string& m) { return Status(StatusCode::kInvalidArgument, "ClientOptions." + m); };
  if (o.target.empty()) return invalid("target: required");
  if (o.robot_id.empty()) return invalid("robot_id: required");
  if (o.robot_id.size() > 128) return invalid("robot_id: longer than 128 bytes");
  if (o.session_id.size() > 128) return invalid("session_id: longer than 128 bytes");
  if (o.insert_queue_capacity == 0) return invalid("insert_queue_capacity: must be at least 1");
  if (o.result_history == 0) return invalid("result_history: must be at least 1");
  if (o.write_attempt_timeout.count() <= 0) return invalid("write_attempt_timeout: must be positive");
  if (o.query_timeout.count() <= 0) return invalid("query_timeout: must be positive");
  if (o.call_timeout.count() <= 0) return invalid("call_timeout: must be positive");
  if (o.retry_backoff_initial.count() <= 0 || o.retry_backoff_max < o.retry_backoff_initial) {
    return invalid("retry_backoff_initial/max: need 0 < initial <= max");
  }
  if (o.reconnect_backoff_max.count() <= 0) return invalid("reconnect_backoff_max: must be positive");
  if (o.max_message_bytes < 1024) return invalid("max_message_bytes: must be at least 1024");
  return Status::Ok();
}

}  // namespace

class VprClient::Impl {
 public:
  Impl(const ClientOptions& options, const std::shared_ptr<grpc::ChannelCredentials>& credentials)
      : options_(options),
        session_id_(options.session_id),
        channel_(internal::MakeChannel(options, credentials)),
        stub_(v1::PlaceRecognition::NewStub(channel_)),
        board_(options.result_history),
        writer_(stub_.get(), &calls_, options),
        loop_(QueryKind::kLoopClosure, stub_.get(), &calls_, &board_, options.query_timeout,
              options.on_query_result, [this] { return writer_.finished_through(); },
              [this] { return writer_.log_position(); }),
        reloc_(QueryKind::kRelocalisation, stub_.get(), &calls_, &board_, options.query_timeout,
               options.on_query_result, [this] { return writer_.finished_through(); },
               [this] { return writer_.log_position(); }) {
    // Queries held back for writes (QueryRequest::after_queued_writes)
    // re-check when a write finishes. The writer thread is joined in Close()
    // before the lanes go away.
    writer_.SetOnProgress([this] {
      loop_.WritesProgressed();
      reloc_.WritesProgressed();
    });
  }

  ~Impl() { Close(options_.close_drain_timeout); }

  const ClientOptions& options() const { return options_; }

  std::string session() const {
    std::lock_guard<std::mutex> lock(session_mutex_);
    return session_id_;
  }
  void set_session(const std::string& session_id) {
    std::lock_guard<std::mutex> lock(session_mutex_);
    session_id_ = session_id;
  }

  // Queues a write and, if asked, waits for its outcome.
  WriteResult Write(internal::WriteOp op, std::chrono::milliseconds wait) {
    auto done = std::make_shared<std::promise<WriteResult>>();
    std::future<WriteResult> outcome = done->get_future();
    op.done = done;
    const Clock::time_point deadline = Clock::now() + std::max(wait, std::chrono::milliseconds(0));
    WriteResult result;
    const Status queued = writer_.Enqueue(std::move(op), deadline, &result.sequence);
    if (!queued.ok()) {
      result.state = WriteState::kFailed;
      result.status = queued;
      return result;
    }
    if (wait.count() <= 0) return result;  // kQueued, OK
    if (outcome.wait_until(deadline) == std::future_status::ready) return outcome.get();
    result.status = Status(StatusCode::kDeadlineExceeded,
                           "write " + std::to_string(result.sequence) + " not applied within " +
                               std::to_string(wait.count()) + " ms; it stays queued and will be applied in order");
    return result;
  }

  Ticket Submit(const QueryRequest& request) {
    v1::QueryRequest proto;
    internal::ToProto(request, options_.robot_id, session(), &proto);
    internal::QueryLane& lane = request.kind == QueryKind::kRelocalisation ? reloc_ : loop_;
    // Every write queued before this call has a sequence up to last_queued().
    const uint64_t after_write = request.after_queued_writes ? writer_.last_queued() : 0;
    return lane.Submit(std::move(proto), after_write);
  }

  QueryResult WaitFor(Ticket ticket, Clock::time_point deadline) { return board_.WaitFor(ticket, deadline); }
  bool Latest(QueryKind kind, QueryResult* out) { return board_.TakeLatest(kind, out); }

  Status Stats(StoreStats* out) {
    if (closed_) return Status(StatusCode::kCancelled, "the client is closed");
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + options_.call_timeout);
    v1::StatsResponse response;
    grpc::Status status;
    {
      internal::ScopedCall call(&calls_, &context);
      status = stub_->Stats(&context, v1::StatsRequest(), &response);
    }
    if (!status.ok()) return internal::FromGrpc(status);
    internal::FromProto(response, out);
    return Status::Ok();
  }

  Status Flush(std::chrono::milliseconds timeout) { return writer_.Flush(Clock::now() + timeout); }
  WriteStats write_stats() const { return writer_.stats(); }

  Status Close(std::chrono::milliseconds drain) {
    std::lock_guard<std::mutex> lock(close_mutex_);
    if (closed_) return close_status_;
    closed_ = true;
    // Writes drain first; then every call still in flight is cancelled
    // (Writer::Close cancels through the shared registry) and the query
    // lanes resolve what they hold.
    const uint64_t dropped = writer_.Close(Clock::now() + drain);
    loop_.Close();
    reloc_.Close();
    if (dropped > 0) {
      close_status_ = Status(StatusCode::kAborted, std::to_string(dropped) +
                                                       " writes were not delivered before the client closed "
                                                       "(reported to on_write_failed)");
    }
    return close_status_;
  }

 private:
  const ClientOptions options_;
  mutable std::mutex session_mutex_;
  std::string session_id_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::PlaceRecognition::Stub> stub_;
  internal::CallRegistry calls_;
  internal::ResultBoard board_;
  internal::Writer writer_;
  internal::QueryLane loop_;
  internal::QueryLane reloc_;
  std::mutex close_mutex_;
  std::atomic<bool> closed_{false};
  Status close_status_;
};

// ---------------------------------------------------------------------------

std::unique_ptr<VprClient> VprClient::Create(const ClientOptions& options, Status* status) {
  Status checked = CheckOptions(options);
  std::shared_ptr<grpc::ChannelCredentials> credentials;
  if (checked.ok()) checked = internal::MakeCredentials(options, &credentials);
  if (status) *status = checked;
  if (!checked.ok()) return nullptr;
  return std::unique_ptr<VprClient>(new VprClient(new Impl(options, credentials)));
}

VprClient::VprClient(Impl* impl) : impl_(impl) {}

VprClient::~VprClient() = default;

WriteResult VprClient::Insert(const Keyframe& keyframe, std::chrono::milliseconds wait) {
  auto request = std::make_shared<v1::InsertRequest>();
  internal::ToProto(keyframe, impl_->options().robot_id, impl_->session(), request->mutable_keyframe());
  internal::WriteOp op;
  op.kind = WriteKind::kInsert;
  op.keyframe_id = keyframe.keyframe_id;
  op.bounded = true;
  op.send = [request](internal::Stub& stub, grpc::ClientContext& context, WriteResult& result) {
    v1::InsertResponse response;
    grpc::Status status = stub.Insert(&context, *request, &response);
    result.log_sequence = response.log_sequence();
    result.replaced = response.replaced();
    result.store_keyframes = response.store_keyframes();
    result.affected = 1;
    return status;
  };
  return impl_->Write(std::move(op), wait);
}

WriteResult VprClient::Erase(const std::vector<uint64_t>& keyframe_ids, std::chrono::milliseconds wait) {
  auto request = std::make_shared<v1::EraseRequest>();
  request->set_robot_id(impl_->options().robot_id);
  request->set_session_id(impl_->session());
  request->mutable_keyframe_ids()->Assign(keyframe_ids.begin(), keyframe_ids.end());
  internal::WriteOp op;
  op.kind = WriteKind::kErase;
  op.send = [request](internal::Stub& stub, grpc::ClientContext& context, WriteResult& result) {
    v1::EraseResponse response;
    grpc::Status status = stub.Erase(&context, *request, &response);
    result.log_sequence = response.log_sequence();
    result.affected = response.erased();
    return status;
  };
  return impl_->Write(std::move(op), wait);
}

WriteResult VprClient::ResetMap(uint64_t map_id, std::chrono::milliseconds wait) {
  auto request = std::make_shared<v1::ResetMapRequest>();
  request->set_robot_id(impl_->options().robot_id);
  request->set_session_id(impl_->session());
  request->set_map_id(map_id);
  internal::WriteOp op;
  op.kind = WriteKind::kResetMap;
  op.send = [request](internal::Stub& stub, grpc::ClientContext& context, WriteResult& result) {
    v1::ResetMapResponse response;
    grpc::Status status = stub.ResetMap(&context, *request, &response);
    result.log_sequence = response.log_sequence();
    result.affected = response.erased();
    return status;
  };
  return impl_->Write(std::move(op), wait);
}

WriteResult VprClient::ResetSession(std::chrono::milliseconds wait) {
  auto request = std::make_shared<v1::ResetSessionRequest>();
  request->set_robot_id(impl_->options().robot_id);
  request->set_session_id(impl_->session());
  internal::WriteOp op;
  op.kind = WriteKind::kResetSession;
  op.send = [request](internal::Stub& stub, grpc::ClientContext& context, WriteResult& result) {
    v1::ResetSessionResponse response;
    grpc::Status status = stub.ResetSession(&context, *request, &response);
    result.log_sequence = response.log_sequence();
    result.affected = response.erased();
    return status;
  };
  return impl_->Write(std::move(op), wait);
}

WriteResult VprClient::UpdatePoses(const std::vector<PoseUpdate>& updates, std::chrono::milliseconds wait) {
  auto request = std::make_shared<v1::UpdatePosesRequest>();
  request->set_robot_id(impl_->options().robot_id);
  request->set_session_id(impl_->session());
  for (const PoseUpdate& u : updates) internal::ToProto(u, request->add_updates());
  internal::WriteOp op;
  op.kind = WriteKind::kUpdatePoses;
  op.send = [request](internal::Stub& stub, grpc::ClientContext& context, WriteResult& result) {
    v1::UpdatePosesResponse response;
    grpc::Status status = stub.UpdatePoses(&context, *request, &response);
    result.log_sequence = response.log_sequence();
    result.affected = response.updated();
    result.missing_keyframe_ids.assign(response.missing_keyframe_ids().begin(),
                                       response.missing_keyframe_ids().end());
    return status;
  };
  return impl_->Write(std::move(op), wait);
}

WriteResult VprClient::ReportVerification(const Verification& verdict, std::chrono::milliseconds wait) {
  auto request = std::make_shared<v1::ReportVerificationRequest>();
  internal::ToProto(verdict, impl_->options().robot_id, impl_->session(), request.get());
  internal::WriteOp op;
  op.kind = WriteKind::kReportVerification;
  op.keyframe_id = verdict.keyframe_id;
  op.send = [request](internal::Stub& stub, grpc::ClientContext& context, WriteResult& result) {
    v1::ReportVerificationResponse response;
    grpc::Status status = stub.ReportVerification(&context, *request, &response);
    result.log_sequence = response.log_sequence();
    result.replaced = response.replaced();
    result.store_verdicts = response.store_verdicts();
    result.affected = 1;
    return status;
  };
  return impl_->Write(std::move(op), wait);
}

Status VprClient::Flush(std::chrono::milliseconds timeout) { return impl_->Flush(timeout); }

WriteStats VprClient::GetWriteStats() const { return impl_->write_stats(); }

Ticket VprClient::SubmitQuery(const QueryRequest& request) { return impl_->Submit(request); }

QueryResult VprClient::WaitFor(Ticket ticket, Clock::time_point deadline) { return impl_->WaitFor(ticket, deadline); }

QueryResult VprClient::WaitFor(Ticket ticket, std::chrono::milliseconds timeout) {
  return impl_->WaitFor(ticket, Clock::now() + timeout);
}

bool VprClient::Latest(QueryKind kind, QueryResult* out) { return impl_->Latest(kind, out); }

Status VprClient::Stats(StoreStats* out) { return impl_->Stats(out); }

void VprClient::SetSession(const std::string& session_id) { impl_->set_session(session_id); }

std::string VprClient::session_id() const { return impl_->session(); }

const std::string& VprClient::robot_id() const { return impl_->options().robot_id; }

Status VprClient::Close(std::chrono::milliseconds drain) { return impl_->Close(drain); }

}  // namespace humem
