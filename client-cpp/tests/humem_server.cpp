// Job: the `humem serve` process control declared in humem_server.h.
#include "humem_server.h"

#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <poll.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

extern char** environ;

namespace humem_test {

TempDir::TempDir() {
  const char* base = std::getenv("TMPDIR");
  std::string pattern = std::string(base && *base ? base : "/tmp") + "/humem-client-test-XXXXXX";
  std::vector<char> buf(pattern.begin(), pattern.end());
  buf.push_back('\0');
  if (mkdtemp(buf.data()) == nullptr) {
    std::perror("mkdtemp");
    std::abort();
  }
  path_ = buf.data();
}

TempDir::~TempDir() {
  std::error_code ignored;
  std::filesystem::remove_all(path_, ignored);
}

std::string HumemServer::Binary() {
  const char* env = std::getenv("HUMEM_BIN");
  if (!env || !*env) return HUMEM_BIN_DEFAULT;
  // A relative path is taken from the working directory if it names a file
  // there, else from the repository root (ctest runs tests in the build tree).
  const std::filesystem::path bin(env);
  if (bin.is_absolute() || std::filesystem::exists(bin)) return bin.string();
  return (std::filesystem::path(HUMEM_REPO_ROOT) / bin).lexically_normal().string();
}

HumemServer::HumemServer(std::string data_dir, std::vector<std::string> env)
    : data_dir_(std::move(data_dir)), env_(std::move(env)) {}

HumemServer::~HumemServer() { Kill(); }

std::string HumemServer::address() const { return "127.0.0.1:" + std::to_string(port_); }

std::string HumemServer::TlsDir() {
  const char* dir = std::getenv("HUMEM_TEST_TLS_DIR");
  return dir ? dir : "";
}

void HumemServer::Connect(humem::ClientOptions* options) const {
  const std::string tls = TlsDir();
  if (tls.empty()) {
    options->target = address();
    return;
  }
  options->target = "https://" + address();
  options->tls_ca_file = tls + "/ca.crt";
  // The certificate names "localhost"; the target is an IP address.
  options->tls_server_name = "localhost";
  // The token `humem token add` printed into the directory.
  std::ifstream token(tls + "/token");
  std::getline(token, options->auth_token);
}

bool HumemServer::Start() {
  if (pid_ > 0) {
    error_ = "already running";
    return false;
  }
  const std::string binary = Binary();
  if (access(binary.c_str(), X_OK) != 0) {
    error_ = "humem binary not found or not executable at " + binary +
             " (build it with `cargo build --bin humem`, or set HUMEM_BIN)";
    return false;
  }
  // A restart on the same port may race the old socket's release: retry.
  for (int attempt = 0; attempt < 50; ++attempt) {
    bool retry = false;
    if (StartOnce(&retry)) return true;
    if (!retry || port_ == 0) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return false;
}

bool HumemServer::StartOnce(bool* retry) {
  const std::string binary = Binary();
  int fds[2];
  if (pipe2(fds, O_CLOEXEC) != 0) {
    error_ = std::string("pipe2: ") + std::strerror(errno);
    return false;
  }
  // The environment: ours minus every HUMEM_* variable (the server refuses
  // unknown ones, e.g. HUMEM_BIN, and known ones would configure it
  // differently) and RUST_LOG, plus the test settings.
  std::vector<std::string> env;
  for (char** e = environ; *e; ++e) {
    if (std::strncmp(*e, "HUMEM_", 6) == 0 || std::strncmp(*e, "RUST_LOG=", 9) == 0) continue;
    env.push_back(*e);
  }
  env.push_back("RUST_LOG=warn");
  env.push_back("HUMEM_PERCEPTION__ENABLED=false");
  env.push_back("HUMEM_METRICS__LISTEN=127.0.0.1:0");
  // The client's tests store a handful of keyframes: too few for the
  // server's calibrated scores (no null below vpr.null_min_samples), so they
  // run with the paper's raw rule; what they check is the client, not the
  // scoring.
  env.push_back("HUMEM_VPR__CALIBRATION=raw");
  const std::string tls = TlsDir();
  if (!tls.empty()) {
    env.push_back("HUMEM_SERVER__TLS__CERT=" + tls + "/tls.crt");
    env.push_back("HUMEM_SERVER__TLS__KEY=" + tls + "/tls.key");
    env.push_back("HUMEM_AUTH__TOKENS_FILE=" + tls + "/tokens.json");
  }
  for (const std::string& e : env_) env.push_back(e);
  std::vector<char*> envp;
  for (std::string& e : env) envp.push_back(e.data());
  envp.push_back(nullptr);

  std::string listen = "127.0.0.1:" + std::to_string(port_);
  std::vector<std::string> args = {binary, "serve", "--listen", listen, "--data-dir", data_dir_};
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);

  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, fds[1], STDOUT_FILENO);
  pid_t pid;
  const int rc = posix_spawn(&pid, binary.c_str(), &actions, nullptr, argv.data(), envp.data());
  posix_spawn_file_actions_destroy(&actions);
  close(fds[1]);
  if (rc != 0) {
    close(fds[0]);
    error_ = "posix_spawn " + binary + ": " + std::strerror(rc);
    return false;
  }

  // Read stdout lines until the address is announced.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  std::string buffer;
  std::string address;
  while (address.empty()) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) break;
    pollfd p{fds[0], POLLIN, 0};
    if (poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
    char chunk[512];
    const ssize_t n = read(fds[0], chunk, sizeof chunk);
    if (n <= 0) break;  // exited
    buffer.append(chunk, static_cast<size_t>(n));
    size_t eol;
    while ((eol = buffer.find('\n')) != std::string::npos) {
      const std::string line = buffer.substr(0, eol);
      buffer.erase(0, eol + 1);
      static const std::string kListening = "humem listening on ";
      if (line.compare(0, kListening.size(), kListening) == 0) address = line.substr(kListening.size());
    }
  }
  if (address.empty()) {
    kill(pid, SIGKILL);
    int status = 0;
    waitpid(pid, &status, 0);
    close(fds[0]);
    error_ = "humem serve (" + listen + ", data dir " + data_dir_ +
             ") did not report its address; exit status " + std::to_string(status) + " (see its stderr above)";
    *retry = true;
    return false;
  }
  port_ = std::atoi(address.substr(address.rfind(':') + 1).c_str());
  pid_ = pid;
  stdout_fd_ = fds[0];
  frozen_ = false;
  // Keep reading stdout so the server never blocks on a full pipe.
  const int fd = stdout_fd_;
  drain_ = std::thread([fd] {
    char chunk[512];
    while (read(fd, chunk, sizeof chunk) > 0) {
    }
  });
  error_.clear();
  return true;
}

void HumemServer::Reap(int signal) {
  if (pid_ <= 0) return;
  kill(pid_, signal);
  if (frozen_ && signal != SIGKILL) kill(pid_, SIGCONT);
  int status = 0;
  waitpid(pid_, &status, 0);
  pid_ = -1;
  frozen_ = false;
  if (drain_.joinable()) drain_.join();
  close(stdout_fd_);
  stdout_fd_ = -1;
  exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

void HumemServer::Kill() { Reap(SIGKILL); }

int HumemServer::Terminate() {
  if (pid_ <= 0) return -1;
  Reap(SIGTERM);
  return exit_code_;
}

void HumemServer::Freeze() {
  if (pid_ > 0 && !frozen_) {
    kill(pid_, SIGSTOP);
    int status = 0;
    waitpid(pid_, &status, WUNTRACED);  // returns once it has stopped
    frozen_ = true;
  }
}

void HumemServer::Thaw() {
  if (pid_ > 0 && frozen_) {
    kill(pid_, SIGCONT);
    int status = 0;
    waitpid(pid_, &status, WCONTINUED);
    frozen_ = false;
  }
}

}  // namespace humem_test
