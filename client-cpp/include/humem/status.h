// Job: the client's error type. Every call reports a Status: a gRPC status
// code (the server's, or one the client chose with the same meaning) plus a
// human-readable message, e.g. INVALID_ARGUMENT
// "keyframe.features.descriptor[3]: not a finite number".
//
// Header-only and C++11, like every public header of this library.
#ifndef HUMEM_STATUS_H_
#define HUMEM_STATUS_H_

#include <string>

namespace humem {

// The gRPC status codes, with their gRPC numbers.
enum class StatusCode : int {
  kOk = 0,
  kCancelled = 1,
  kUnknown = 2,
  kInvalidArgument = 3,
  kDeadlineExceeded = 4,
  kNotFound = 5,
  kAlreadyExists = 6,
  kPermissionDenied = 7,
  kResourceExhausted = 8,
  kFailedPrecondition = 9,
  kAborted = 10,
  kOutOfRange = 11,
  kUnimplemented = 12,
  kInternal = 13,
  kUnavailable = 14,
  kDataLoss = 15,
  kUnauthenticated = 16,
};

// "OK", "INVALID_ARGUMENT", ...
inline const char* StatusCodeName(StatusCode code) {
  switch (code) {
    case StatusCode::kOk: return "OK";
    case StatusCode::kCancelled: return "CANCELLED";
    case StatusCode::kUnknown: return "UNKNOWN";
    case StatusCode::kInvalidArgument: return "INVALID_ARGUMENT";
    case StatusCode::kDeadlineExceeded: return "DEADLINE_EXCEEDED";
    case StatusCode::kNotFound: return "NOT_FOUND";
    case StatusCode::kAlreadyExists: return "ALREADY_EXISTS";
    case StatusCode::kPermissionDenied: return "PERMISSION_DENIED";
    case StatusCode::kResourceExhausted: return "RESOURCE_EXHAUSTED";
    case StatusCode::kFailedPrecondition: return "FAILED_PRECONDITION";
    case StatusCode::kAborted: return "ABORTED";
    case StatusCode::kOutOfRange: return "OUT_OF_RANGE";
    case StatusCode::kUnimplemented: return "UNIMPLEMENTED";
    case StatusCode::kInternal: return "INTERNAL";
    case StatusCode::kUnavailable: return "UNAVAILABLE";
    case StatusCode::kDataLoss: return "DATA_LOSS";
    case StatusCode::kUnauthenticated: return "UNAUTHENTICATED";
  }
  return "UNKNOWN";
}

// A status code and its message; default-constructed it is OK.
struct Status {
  StatusCode code;
  std::string message;

  Status() : code(StatusCode::kOk) {}
  Status(StatusCode c, const std::string& m) : code(c), message(m) {}

  static Status Ok() { return Status(); }

  bool ok() const { return code == StatusCode::kOk; }

  // "INVALID_ARGUMENT: keyframe.robot_id: required", or "OK".
  std::string ToString() const {
    std::string s = StatusCodeName(code);
    if (!message.empty()) {
      s += ": ";
      s += message;
    }
    return s;
  }
};

}  // namespace humem

#endif  // HUMEM_STATUS_H_
