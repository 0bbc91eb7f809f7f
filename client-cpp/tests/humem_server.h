// Job: runs the real `humem serve` for the server tests, the way
// tests/e2e/harness.rs does: perception off (tests send feature vectors),
// metrics on a free port, the store in a temporary directory, the gRPC port
// read from the "humem listening on ADDR" line. Also stops, kills, freezes
// (SIGSTOP) and restarts it on the same port and data directory.
//
// With HUMEM_TEST_TLS_DIR set (a directory holding ca.crt, tls.crt and
// tls.key for "localhost", a token file tokens.json and the token in
// `token`, as scripts/test-client-cpp.sh makes them), the server serves TLS
// and requires tokens, and Connect() points clients at it over https://
// with the token, so the whole suite runs over TLS with a token.
#ifndef HUMEM_TESTS_HUMEM_SERVER_H_
#define HUMEM_TESTS_HUMEM_SERVER_H_

#include <string>
#include <sys/types.h>
#include <thread>
#include <vector>

#include "humem/vpr_client.h"

namespace humem_test {

// A fresh directory under $TMPDIR (or /tmp), removed with its contents.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

class HumemServer {
 public:
  // The binary: $HUMEM_BIN (relative: to the working directory, else to
  // the repository root), else the CMake cache variable HUMEM_BIN.
  static std::string Binary();

  // Configures (does not start) a server on 127.0.0.1:`port` (0: any free
  // port) storing in `data_dir`; `env` adds KEY=VALUE settings.
  explicit HumemServer(std::string data_dir, std::vector<std::string> env = {});
  ~HumemServer();  // SIGKILL if still running
  HumemServer(const HumemServer&) = delete;
  HumemServer& operator=(const HumemServer&) = delete;

  // Starts it and waits (up to 60 s) until it listens. After a first start,
  // restarts on the same port. False with error() set on failure.
  bool Start();
  const std::string& error() const { return error_; }

  // "127.0.0.1:PORT" once started.
  std::string address() const;
  // Points `options` at this server: the target, and the TLS settings when
  // the tests run over TLS.
  void Connect(humem::ClientOptions* options) const;
  // The TLS directory the tests run with, or "" for plaintext.
  static std::string TlsDir();
  int port() const { return port_; }
  pid_t pid() const { return pid_; }

  void Kill();       // SIGKILL (no chance to flush), waits
  int Terminate();   // SIGTERM, waits; the exit code (-1 if killed by a signal)
  void Freeze();     // SIGSTOP: connections stay open, nothing is answered
  void Thaw();       // SIGCONT

 private:
  bool StartOnce(bool* retry);
  void Reap(int signal);

  std::string data_dir_;
  std::vector<std::string> env_;
  int port_ = 0;
  pid_t pid_ = -1;
  int stdout_fd_ = -1;
  bool frozen_ = false;
  int exit_code_ = 0;
  std::thread drain_;
  std::string error_;
};

}  // namespace humem_test

#endif  // HUMEM_TESTS_HUMEM_SERVER_H_
