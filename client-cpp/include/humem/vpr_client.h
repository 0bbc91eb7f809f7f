// Job: humem::VprClient, the SLAM system's connection to a HuMem server.
//
// Writes (Insert, Erase, ResetMap, ResetSession, UpdatePoses,
// ReportVerification) go through one ordered, bounded queue and a writer
// thread that delivers them one by one, retrying with back-off while the server is unavailable, overloaded
// (RESOURCE_EXHAUSTED, honouring its `retry-after-ms` hint) or restarting.
// Queries are latest-wins per kind: at most one in flight and one pending;
// a newer submission replaces the pending one. gRPC is hidden behind a
// pimpl: this header compiles as C++11 and includes no gRPC or protobuf.
#ifndef HUMEM_VPR_CLIENT_H_
#define HUMEM_VPR_CLIENT_H_

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "humem/export.h"
#include "humem/status.h"
#include "humem/types.h"

namespace humem {

enum class WriteKind : int { kInsert = 1, kErase, kResetMap, kResetSession, kUpdatePoses, kReportVerification };

enum class WriteState : int {
  kQueued = 1,   // accepted by the client, not yet acknowledged by the server
  kApplied = 2,  // acknowledged: durable on the server
  kFailed = 3,   // refused (by the server, or by the client: queue full,
                 // client closed); `status` says why
};

// The outcome of a write, as far as it is known when the call returns.
struct WriteResult {
  WriteState state;
  // kApplied: OK. kQueued: OK if the caller did not wait, DEADLINE_EXCEEDED
  // if it waited and the write is still queued (it stays queued and will be
  // applied in order). kFailed: the error.
  Status status;
  uint64_t sequence;  // position in the write order (0 if never queued)
  // Once applied: Insert: whether it replaced a stored keyframe and the
  // store's size; Erase/ResetMap/ResetSession: keyframes removed;
  // UpdatePoses: keyframes updated and the ids the server does not hold;
  // ReportVerification: whether it replaced a stored verdict on the same
  // query, candidate and kind, and the store's verdict count.
  bool replaced;
  uint64_t store_keyframes;
  uint64_t affected;
  uint64_t store_verdicts;
  std::vector<uint64_t> missing_keyframe_ids;
  // A server in cluster mode: the write's position in its write log; the
  // client's later queries ask any replica to have applied it first
  // (read-your-writes). 0 from a server not in cluster mode.
  uint64_t log_sequence;

  WriteResult()
      : state(WriteState::kQueued), sequence(0), replaced(false), store_keyframes(0), affected(0), store_verdicts(0),
        log_sequence(0) {}
  bool applied() const { return state == WriteState::kApplied; }
};

// A write that will never be applied, reported to ClientOptions::on_write_failed.
struct WriteFailure {
  uint64_t sequence;
  WriteKind kind;
  uint64_t keyframe_id;  // Insert: the keyframe; ReportVerification: the query keyframe
  Status status;
  WriteFailure() : sequence(0), kind(WriteKind::kInsert), keyframe_id(0) {}
};

// Counters of the write queue since the client started.
struct WriteStats {
  size_t queued;               // waiting, not counting the one in flight
  bool in_flight;              // one write is being delivered
  uint64_t applied;            // acknowledged by the server
  uint64_t failed;             // refused for good (also reported by callback)
  uint64_t retries;            // attempts repeated after a transient error
  uint64_t resource_exhausted; // of which after RESOURCE_EXHAUSTED
  uint64_t abandoned;          // dropped undelivered by Close()
  Status last_transient;       // the latest transient error seen
  WriteStats()
      : queued(0), in_flight(false), applied(0), failed(0), retries(0), resource_exhausted(0),
        abandoned(0) {}
};

struct ClientOptions {
  // The server: "host:port", or "http://host:port" (as in HUMEM_SERVER_URL);
  // "https://host:port" connects over TLS.
  std::string target;
  // TLS, for an "https://" target only. tls_ca_file: PEM bundle of the CAs
  // the server's certificate must chain to (empty: gRPC's default roots).
  // tls_cert_file and tls_key_file (both or neither): the client's PEM
  // certificate chain and key, for a server that requires mutual TLS.
  // tls_server_name: the name checked against the server's certificate,
  // when it is not the target's host (e.g. connecting by IP address).
  std::string tls_ca_file;
  std::string tls_cert_file;
  std::string tls_key_file;
  std::string tls_server_name;
  // Bearer token from `humem token add`, sent with every call as
  // "authorization: Bearer <token>"; only over TLS (an "https://" target).
  std::string auth_token;
  // Robot and session that every request is made for. robot_id is required.
  std::string robot_id;
  std::string session_id;

  // Inserts waiting to be delivered before Insert() pushes back with
  // RESOURCE_EXHAUSTED (other writes are always accepted: they are few and
  // must keep their order).
  size_t insert_queue_capacity;
  // Deadline of one write attempt (it waits for the connection meanwhile).
  std::chrono::milliseconds write_attempt_timeout;
  // Deadline of one query RPC (queries fail fast while disconnected).
  std::chrono::milliseconds query_timeout;
  // Deadline of Stats().
  std::chrono::milliseconds call_timeout;
  // Retry back-off of writes: doubles from initial to max, ±20% jitter;
  // never shorter than the server's retry-after-ms hint.
  std::chrono::milliseconds retry_backoff_initial;
  std::chrono::milliseconds retry_backoff_max;
  // Longest gap between gRPC's reconnection attempts (its default is 120 s,
  // far too long to notice a restarted server).
  std::chrono::milliseconds reconnect_backoff_max;
  // How long the destructor lets queued writes drain before dropping them.
  std::chrono::milliseconds close_drain_timeout;
  // Resolved query results kept for WaitFor (the oldest are forgotten).
  size_t result_history;
  // Largest message sent or received.
  int max_message_bytes;

  // Called for each write that will never be applied: from the writer
  // thread when the server refuses it, from Close()'s caller for writes it
  // drops. Keep it short; do not call the client from it.
  std::function<void(const WriteFailure&)> on_write_failed;
  // Called for every resolved ticket: from the query thread of its kind, or
  // from the SubmitQuery caller's thread when it supersedes a pending ticket
  // (or Close()'s, for tickets it cancels). Keep it short.
  std::function<void(const QueryResult&)> on_query_result;

  ClientOptions()
      : target("127.0.0.1:50051"),
        insert_queue_capacity(128),
        write_attempt_timeout(10000),
        query_timeout(5000),
        call_timeout(5000),
        retry_backoff_initial(50),
        retry_backoff_max(2000),
        reconnect_backoff_max(1000),
        close_drain_timeout(2000),
        result_history(64),
        max_message_bytes(64 << 20) {}
};

// Thread-safe: every method may be called from any thread.
class HUMEM_API VprClient {
 public:
  typedef std::chrono::steady_clock Clock;

  // Starts a client (its threads and a lazily connecting channel; the
  // server need not be up). Returns null and sets *status on bad options.
  static std::unique_ptr<VprClient> Create(const ClientOptions& options, Status* status);

  // Close(close_drain_timeout) unless closed already.
  ~VprClient();

  // ---- writes: ordered, retried until applied or refused ------------------
  // Each returns once the write is queued, or, with wait > 0, once it is
  // applied or refused or `wait` has passed (then it stays queued). Insert
  // also waits up to `wait` for room in a full queue.

  WriteResult Insert(const Keyframe& keyframe,
                     std::chrono::milliseconds wait = std::chrono::milliseconds(0));
  WriteResult Erase(const std::vector<uint64_t>& keyframe_ids,
                    std::chrono::milliseconds wait = std::chrono::milliseconds(0));
  WriteResult ResetMap(uint64_t map_id, std::chrono::milliseconds wait = std::chrono::milliseconds(0));
  // Removes every keyframe of the current session (ORB-SLAM3's full reset,
  // after which keyframe ids restart).
  WriteResult ResetSession(std::chrono::milliseconds wait = std::chrono::milliseconds(0));
  WriteResult UpdatePoses(const std::vector<PoseUpdate>& updates,
                          std::chrono::milliseconds wait = std::chrono::milliseconds(0));
  // Reports the SLAM system's geometric verdict on a candidate HuMem
  // proposed (the server stores it with the two keyframes and uses it in
  // later answers: Evidence::verdict_penalty / verdict_support). Queued
  // like the other writes, so it is sent after the inserts made before it:
  // report right after inserting and the keyframes it names are stored
  // first. The server refuses it with NOT_FOUND when the query keyframe or
  // the candidate is not stored (reported like any refused write: the
  // result's status with a `wait`, and on_write_failed).
  WriteResult ReportVerification(const Verification& verdict,
                                 std::chrono::milliseconds wait = std::chrono::milliseconds(0));

  // Waits until every write queued before the call is applied or refused.
  // OK, or DEADLINE_EXCEEDED if `timeout` passed first.
  Status Flush(std::chrono::milliseconds timeout);

  WriteStats GetWriteStats() const;

  // ---- queries: latest wins per kind ---------------------------------------

  // Queues the query in its kind's slot and returns its ticket at once. A
  // query already pending in that slot resolves as kSuperseded.
  Ticket SubmitQuery(const QueryRequest& request);

  // Waits until the ticket resolves or `deadline` passes; then returns its
  // state (kQueued/kInFlight with DEADLINE_EXCEEDED if still unresolved).
  // Never blocks past the deadline.
  QueryResult WaitFor(Ticket ticket, Clock::time_point deadline);
  QueryResult WaitFor(Ticket ticket, std::chrono::milliseconds timeout);

  // Non-blocking. If a query of this kind was answered by the server (or
  // failed, or was superseded there) since the last call, moves the newest
  // such result to *out and returns true. Results superseded inside the
  // client never show up here.
  bool Latest(QueryKind kind, QueryResult* out);

  // ---- other ----------------------------------------------------------------

  // What the server's store holds (a read: queued writes are not waited for).
  Status Stats(StoreStats* out);

  // Changes the session of later requests (already queued writes keep theirs).
  void SetSession(const std::string& session_id);
  std::string session_id() const;
  const std::string& robot_id() const;

  // Stops the client: lets queued writes drain for up to `drain`, then
  // cancels what is in flight, resolves pending queries as CANCELLED, reports
  // undelivered writes to on_write_failed and joins the threads. OK if
  // nothing was dropped, else ABORTED naming how many writes were. Later
  // calls fail with CANCELLED. Idempotent.
  Status Close(std::chrono::milliseconds drain);

 private:
  class Impl;
  explicit VprClient(Impl* impl);
  VprClient(const VprClient&);             // not copyable
  VprClient& operator=(const VprClient&);  // not copyable
  std::unique_ptr<Impl> impl_;
};

}  // namespace humem

#endif  // HUMEM_VPR_CLIENT_H_
