#include "service/service_testutil.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <httplib.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <random>
#include <regex>
#include <set>
#include <sstream>
#include <thread>
#include <unordered_map>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "tandem/common/wire.h"
#include "tandem/eval/synthetic.h"
#include "tandem/io/open_volume.h"
#include "tandem/io/run_session.h"
#include "tandem/io/volume_writers.h"
#include "testutil/testutil.h"

extern char** environ;

namespace tandem::testing {
namespace {

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::chrono::system_clock::time_point In(double seconds) {
  return std::chrono::system_clock::now() +
         std::chrono::milliseconds(static_cast<int64_t>(seconds * 1000));
}

}  // namespace

absl::StatusOr<std::unique_ptr<ChildProcess>> ChildProcess::Spawn(
    const std::vector<std::string>& argv, const std::string& dir,
    const std::vector<std::string>& env) {
  static std::atomic<int> counter{0};
  auto child = std::unique_ptr<ChildProcess>(new ChildProcess());
  const int n = counter++;
  child->out_path_ = absl::StrCat(dir, "/proc_", n, ".out");
  child->err_path_ = absl::StrCat(dir, "/proc_", n, ".err");
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, child->out_path_.c_str(),
                                   O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&actions, 2, child->err_path_.c_str(),
                                   O_WRONLY | O_CREAT | O_TRUNC, 0644);
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  std::vector<std::string> env_strings;
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string entry = *e;
    const std::string name = entry.substr(0, entry.find('='));
    bool replaced = false;
    for (const std::string& add : env) replaced |= add.substr(0, add.find('=')) == name;
    if (!replaced) env_strings.push_back(entry);
  }
  env_strings.insert(env_strings.end(), env.begin(), env.end());
  std::vector<char*> envp;
  for (std::string& e : env_strings) envp.push_back(e.data());
  envp.push_back(nullptr);
  const int rc = posix_spawn(&child->pid_, args[0], &actions, nullptr, args.data(), envp.data());
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) {
    return absl::InternalError(absl::StrCat("posix_spawn ", argv[0], ": ", strerror(rc)));
  }
  return child;
}

ChildProcess::~ChildProcess() {
  if (pid_ > 0 && !exit_code_) {
    kill(pid_, SIGKILL);
    Wait(10);
  }
}

void ChildProcess::Signal(int sig) const {
  if (pid_ > 0 && !exit_code_) kill(pid_, sig);
}

std::optional<int> ChildProcess::Wait(double timeout_s) {
  if (exit_code_) return exit_code_;
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000));
  while (true) {
    int status = 0;
    struct rusage usage {};
    const pid_t r = wait4(pid_, &status, WNOHANG, &usage);
    if (r == pid_) {
      exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      minor_faults_ = usage.ru_minflt;
      return exit_code_;
    }
    if (r < 0 || std::chrono::steady_clock::now() >= deadline) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

std::string ChildProcess::Stdout() const { return ReadAll(out_path_); }
std::string ChildProcess::Stderr() const { return ReadAll(err_path_); }

RunResult RunProcess(const std::vector<std::string>& argv, double timeout_s,
                     const std::vector<std::string>& env) {
  RunResult result;
  auto child = ChildProcess::Spawn(argv, MakeTempDir(), env);
  if (!child.ok()) {
    result.err = std::string(child.status().message());
    return result;
  }
  std::optional<int> code = (*child)->Wait(timeout_s);
  result.exit_code = code.value_or(-1);
  if (!code) (*child)->Signal(SIGKILL);
  result.out = (*child)->Stdout();
  result.err = (*child)->Stderr();
  result.minor_faults = (*child)->minor_faults();
  return result;
}

absl::StatusOr<std::unique_ptr<TestServer>> TestServer::Start(
    const std::vector<std::string>& extra_args, const ClientAuth& auth,
    const std::vector<std::string>& env) {
  std::vector<std::string> argv = {BinPath("tandem-server"), "--listen", "127.0.0.1:0"};
  argv.insert(argv.end(), extra_args.begin(), extra_args.end());
  auto process = ChildProcess::Spawn(argv, MakeTempDir(), env);
  if (!process.ok()) return process.status();
  auto server = std::unique_ptr<TestServer>(new TestServer());
  server->process_ = *std::move(process);
  server->auth_ = auth;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (std::chrono::steady_clock::now() < deadline) {
    const std::string out = server->process_->Stdout();
    const size_t at = out.find("listening on ");
    const size_t eol = out.find('\n', at);
    if (at != std::string::npos && eol != std::string::npos) {
      server->address_ = out.substr(at + 13, eol - at - 13);
      return server;
    }
    if (server->process_->Wait(0)) {
      return absl::InternalError(
          absl::StrCat("tandem-server exited early: ", server->process_->Stderr()));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return absl::DeadlineExceededError("tandem-server did not print its address within 20 s");
}

std::shared_ptr<grpc::ChannelCredentials> TestServer::Credentials() const {
  if (auth_.ca_pem.empty()) return grpc::InsecureChannelCredentials();
  grpc::SslCredentialsOptions ssl;
  ssl.pem_root_certs = auth_.ca_pem;
  return grpc::SslCredentials(ssl);
}

std::unique_ptr<v1::Tandem::Stub> TestServer::NewStub() const {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(common::kClientMaxReceiveBytes);
  return v1::Tandem::NewStub(grpc::CreateCustomChannel(address_, Credentials(), args));
}

void TestServer::AddToken(grpc::ClientContext* context) const {
  if (!auth_.token.empty()) context->AddMetadata("authorization", "Bearer " + auth_.token);
}

absl::StatusOr<v1::InfoResponse> TestServer::Info(
    const std::vector<std::string>& watch_keys) const {
  auto stub = NewStub();
  grpc::ClientContext context;
  context.set_deadline(In(5));
  AddToken(&context);
  v1::InfoResponse info;
  v1::InfoRequest request;
  for (const std::string& key : watch_keys) request.add_watch_keys(key);
  grpc::Status st = stub->GetInfo(&context, request, &info);
  if (!st.ok()) return common::FromGrpcStatus(st);
  return info;
}

std::string TestServer::Health(const std::string& service) const {
  // No token: the health service is open.
  auto stub = grpc::health::v1::Health::NewStub(grpc::CreateChannel(address_, Credentials()));
  grpc::ClientContext context;
  context.set_deadline(In(5));
  grpc::health::v1::HealthCheckResponse response;
  grpc::health::v1::HealthCheckRequest request;
  request.set_service(service);
  grpc::Status st = stub->Check(&context, request, &response);
  if (!st.ok()) {
    return absl::StatusCodeToString(static_cast<absl::StatusCode>(st.error_code()));
  }
  return grpc::health::v1::HealthCheckResponse::ServingStatus_Name(response.status());
}

bool TestServer::WaitIdle(double timeout_s, v1::Counters* last) const {
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000));
  while (true) {
    absl::StatusOr<v1::InfoResponse> info = Info();
    if (info.ok()) {
      const v1::Counters& c = info->counters();
      if (last) *last = c;
      if (c.active_sessions() == 0 && c.worker_threads() == 0 && c.session_bytes() == 0 &&
          c.sessions_started() == c.sessions_finished()) {
        return true;
      }
    }
    if (std::chrono::steady_clock::now() >= deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

absl::StatusOr<std::string> WriteSyntheticVolume(const std::string& dir, const std::string& name,
                                                 std::unique_ptr<SliceSource> source) {
  const std::string path = absl::StrCat(dir, "/", name, ".json");
  SliceSource* src = source.get();
  absl::Status st = io::WriteVolume(path, src->info(), [src](int64_t, std::vector<uint8_t>* bytes) {
    return src->ReadSlice(bytes);
  });
  if (!st.ok()) return st;
  return path;
}

absl::StatusOr<std::string> WriteLoadVolume(const std::string& dir) {
  return WriteSyntheticVolume(dir, "load",
                              eval::MakeSyntheticSource(eval::Shape::kLink, 64, 64, 93));
}

absl::StatusOr<std::string> WritePattern(const std::string& dir, Pattern pattern, int64_t n,
                                         int64_t nz, double* iso) {
  VolumeInfo info;
  info.nx = info.ny = n;
  info.nz = nz;
  info.dtype = DType::kUInt8;
  std::mt19937 rng(62);
  *iso = pattern == Pattern::kNoisyField ? 128 : 127.5;
  const std::string path = absl::StrCat(dir, "/pattern", static_cast<int>(pattern), ".json");
  absl::Status st = io::WriteVolume(path, info, [&](int64_t k, std::vector<uint8_t>* bytes) {
    bytes->resize(static_cast<size_t>(n * n));
    for (int64_t j = 0; j < n; ++j) {
      for (int64_t i = 0; i < n; ++i) {
        uint8_t& v = (*bytes)[static_cast<size_t>(j * n + i)];
        switch (pattern) {
          case Pattern::kNoise: v = static_cast<uint8_t>(rng() >> 24); break;
          case Pattern::kCheckerboard: v = (i + j + k) % 2 == 0 ? 0 : 255; break;
          case Pattern::kNoisyField: {
            const double smooth = 60 * std::sin(static_cast<double>(i) / 40) *
                                  std::cos(static_cast<double>(j) / 50);
            const double noise = static_cast<double>(rng() >> 24) - 127.5;
            v = static_cast<uint8_t>(std::clamp(128 + smooth + noise, 0.0, 255.0));
            break;
          }
        }
      }
    }
    return absl::OkStatus();
  });
  if (!st.ok()) return st;
  return path;
}

absl::StatusOr<std::unique_ptr<TandemSession>> RunLocal(const std::string& path,
                                                        const SessionOptions& options) {
  auto source = io::OpenVolume(path);
  if (!source.ok()) return source.status();
  return io::RunSession(**source, options);
}

absl::StatusOr<std::vector<uint32_t>> MatchVertices(const IndexedMesh& a, const IndexedMesh& b,
                                                    double tol) {
  if (a.num_vertices() != b.num_vertices()) {
    return absl::FailedPreconditionError(
        absl::StrCat(a.num_vertices(), " vs ", b.num_vertices(), " vertices"));
  }
  const double cell = std::max(tol, 1e-12);
  auto key = [cell](const Vec3& p, int dx, int dy, int dz) {
    const int64_t x = static_cast<int64_t>(std::floor(p.x / cell)) + dx;
    const int64_t y = static_cast<int64_t>(std::floor(p.y / cell)) + dy;
    const int64_t z = static_cast<int64_t>(std::floor(p.z / cell)) + dz;
    // (Unsigned: a tiny cell makes large coordinates, and signed overflow is undefined.)
    return static_cast<int64_t>((static_cast<uint64_t>(x) * 73856093u) ^
                                (static_cast<uint64_t>(y) * 19349663u) ^
                                (static_cast<uint64_t>(z) * 83492791u));
  };
  std::unordered_multimap<int64_t, uint32_t> grid;
  for (uint32_t i = 0; i < a.num_vertices(); ++i) grid.emplace(key(a.positions[i], 0, 0, 0), i);
  std::vector<bool> used(a.num_vertices(), false);
  std::vector<uint32_t> map(b.num_vertices());
  for (uint32_t i = 0; i < b.num_vertices(); ++i) {
    const Vec3& p = b.positions[i];
    uint32_t best = kInvalid;
    double best_d = tol;
    for (int dx = -1; dx <= 1; ++dx) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dz = -1; dz <= 1; ++dz) {
          auto [lo, hi] = grid.equal_range(key(p, dx, dy, dz));
          for (auto it = lo; it != hi; ++it) {
            const Vec3& q = a.positions[it->second];
            const double d = std::max({std::abs(p.x - q.x), std::abs(p.y - q.y), std::abs(p.z - q.z)});
            if (!used[it->second] && d <= best_d) {
              best_d = d;
              best = it->second;
            }
          }
        }
      }
    }
    if (best == kInvalid) {
      return absl::NotFoundError(absl::StrCat("vertex ", i, " (", p.x, ", ", p.y, ", ", p.z,
                                              ") has no unmatched original within ", tol));
    }
    used[best] = true;
    map[i] = best;
  }
  return map;
}

bool SameTriangles(const IndexedMesh& a, const IndexedMesh& b, const std::vector<uint32_t>& map) {
  if (a.num_triangles() != b.num_triangles()) return false;
  auto canonical = [](std::array<uint32_t, 3> t) {
    while (t[0] > t[1] || t[0] > t[2]) std::rotate(t.begin(), t.begin() + 1, t.end());
    return t;
  };
  std::vector<std::array<uint32_t, 3>> ta, tb;
  for (size_t t = 0; t < a.num_triangles(); ++t) {
    ta.push_back(canonical({a.indices[3 * t], a.indices[3 * t + 1], a.indices[3 * t + 2]}));
    tb.push_back(canonical(
        {map[b.indices[3 * t]], map[b.indices[3 * t + 1]], map[b.indices[3 * t + 2]]}));
  }
  std::sort(ta.begin(), ta.end());
  std::sort(tb.begin(), tb.end());
  return ta == tb;
}

std::vector<v1::ExtractRequest> VolumeRequests(SliceSource& source,
                                               const v1::SessionConfig& config,
                                               size_t chunk_bytes) {
  const VolumeInfo& info = source.info();
  std::vector<v1::ExtractRequest> out;
  v1::SessionConfig* c = out.emplace_back().mutable_config();
  *c = config;
  c->set_nx(info.nx);
  c->set_ny(info.ny);
  c->set_nz(info.nz);
  c->set_dtype(common::DTypeToProto(info.dtype));
  c->clear_spacing();
  for (double s : info.spacing) c->add_spacing(s);
  std::vector<uint8_t> bytes;
  for (int64_t z = 0; z < info.nz; ++z) {
    if (!source.ReadSlice(&bytes).ok()) break;
    for (size_t off = 0; off < bytes.size(); off += chunk_bytes) {
      v1::SliceChunk* chunk = out.emplace_back().mutable_chunk();
      chunk->set_slice(z);
      chunk->set_offset(off);
      chunk->set_data(bytes.data() + off, std::min(chunk_bytes, bytes.size() - off));
    }
  }
  out.emplace_back().mutable_end()->set_slices(info.nz);
  return out;
}

StreamOutcome RunStream(v1::Tandem::Stub& stub, const std::vector<v1::ExtractRequest>& requests,
                        const TestServer* server) {
  StreamOutcome outcome;
  grpc::ClientContext context;
  context.set_deadline(In(60));
  if (server != nullptr) server->AddToken(&context);
  auto stream = stub.Extract(&context);
  // Writes on a second thread: a server that stops reading must not block the reads.
  std::thread writer([&] {
    for (const v1::ExtractRequest& r : requests) {
      if (!stream->Write(r)) return;
    }
    stream->WritesDone();
  });
  v1::ExtractResponse response;
  while (stream->Read(&response)) outcome.responses.push_back(response);
  writer.join();
  outcome.status = stream->Finish();
  for (const auto& [key, value] : context.GetServerTrailingMetadata()) {
    outcome.trailers[std::string(key.data(), key.size())] = std::string(value.data(), value.size());
  }
  return outcome;
}

std::string ReadFileOrEmpty(const std::string& path) { return ReadAll(path); }

absl::StatusOr<TestPki> MakeTestPki(const std::string& dir) {
  TestPki pki{dir + "/ca.crt", dir + "/server.crt", dir + "/server.key", dir + "/other_ca.crt"};
  std::ofstream(dir + "/san.ext") << "subjectAltName=IP:127.0.0.1,DNS:localhost\n"
                                  << "basicConstraints=CA:FALSE\n"
                                  << "keyUsage=digitalSignature,keyEncipherment\n"
                                  << "extendedKeyUsage=serverAuth\n";
  // EC P-256 keys: fast to generate, and what a modern deployment would use.
  const std::string ec = "ec:" + dir + "/ecparam.pem";
  const std::vector<std::vector<std::string>> steps = {
      {"openssl", "ecparam", "-name", "prime256v1", "-out", dir + "/ecparam.pem"},
      {"openssl", "req", "-x509", "-newkey", ec, "-nodes", "-keyout", dir + "/ca.key", "-out",
       pki.ca_crt, "-days", "2", "-subj", "/CN=tandem test CA"},
      {"openssl", "req", "-newkey", ec, "-nodes", "-keyout", pki.server_key, "-out",
       dir + "/server.csr", "-subj", "/CN=localhost"},
      {"openssl", "x509", "-req", "-in", dir + "/server.csr", "-CA", pki.ca_crt, "-CAkey",
       dir + "/ca.key", "-CAcreateserial", "-out", pki.server_crt, "-days", "2", "-extfile",
       dir + "/san.ext"},
      {"openssl", "req", "-x509", "-newkey", ec, "-nodes", "-keyout", dir + "/other_ca.key",
       "-out", pki.other_ca_crt, "-days", "2", "-subj", "/CN=tandem test CA"},
  };
  for (std::vector<std::string> step : steps) {
    step[0] = "/usr/bin/openssl";
    const RunResult r = RunProcess(step, 30);
    if (r.exit_code != 0) {
      return absl::InternalError(absl::StrCat("openssl ", step[1], " failed (", r.exit_code,
                                              "): ", r.err, " (install it: deploy/install-deps.sh)"));
    }
  }
  return pki;
}

absl::StatusOr<std::unique_ptr<TcpProxy>> TcpProxy::Start(int target_port) {
  std::unique_ptr<TcpProxy> proxy(new TcpProxy());
  proxy->target_port_ = target_port;
  proxy->listen_fd_ = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (proxy->listen_fd_ < 0) return absl::InternalError("socket() failed");
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = 0;
  socklen_t len = sizeof(addr);
  if (bind(proxy->listen_fd_, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0 ||
      listen(proxy->listen_fd_, 16) != 0 ||
      getsockname(proxy->listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0) {
    return absl::InternalError(absl::StrCat("cannot listen on 127.0.0.1: ", std::strerror(errno)));
  }
  proxy->port_ = ntohs(addr.sin_port);
  proxy->acceptor_ = std::thread([p = proxy.get()] { p->AcceptLoop(); });
  return proxy;
}

std::string TcpProxy::address() const { return absl::StrCat("127.0.0.1:", port_); }

void TcpProxy::AcceptLoop() {
  while (!stop_) {
    pollfd pfd{listen_fd_, POLLIN, 0};
    if (poll(&pfd, 1, 50) <= 0) continue;  // re-checks stop_ every 50 ms
    const int client = accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (client < 0) continue;
    const int server = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    addr.sin_port = htons(static_cast<uint16_t>(target_port_));
    if (server < 0 || connect(server, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) {
      close(client);
      if (server >= 0) close(server);
      continue;
    }
    std::lock_guard<std::mutex> lock(mu_);
    fds_.push_back(client);
    fds_.push_back(server);
    forwarders_.emplace_back([this, client, server] { Forward(client, server); });
    forwarders_.emplace_back([this, client, server] { Forward(server, client); });
  }
}

void TcpProxy::Forward(int from, int to) {
  std::vector<char> buf(1 << 16);
  while (!stop_) {
    pollfd pfd{from, POLLIN, 0};
    const int ready = poll(&pfd, 1, 50);
    if (ready == 0) continue;
    if (ready < 0) break;
    const ssize_t got = read(from, buf.data(), buf.size());
    if (got <= 0) break;
    ssize_t off = 0;
    while (off < got) {
      // MSG_NOSIGNAL: a peer gone (the client, after the cut) must end this pump, not the
      // whole test process by SIGPIPE (seen under ASan, where the timing lets it happen).
      const ssize_t put = send(to, buf.data() + off, static_cast<size_t>(got - off), MSG_NOSIGNAL);
      if (put <= 0) break;
      off += put;
    }
    if (off < got) break;
    bytes_ += got;
  }
  shutdown(to, SHUT_RDWR);  // one side ended: end the other
  shutdown(from, SHUT_RDWR);
}

int TcpProxy::CutAll() {
  std::lock_guard<std::mutex> lock(mu_);
  for (int fd : fds_) {
    linger l{1, 0};  // a reset, as a failed network path looks to the peers
    setsockopt(fd, SOL_SOCKET, SO_LINGER, &l, sizeof(l));
    shutdown(fd, SHUT_RDWR);
  }
  return static_cast<int>(fds_.size() / 2);
}

TcpProxy::~TcpProxy() {
  stop_ = true;
  if (acceptor_.joinable()) acceptor_.join();
  std::vector<std::thread> threads;
  {
    std::lock_guard<std::mutex> lock(mu_);
    for (int fd : fds_) shutdown(fd, SHUT_RDWR);
    threads = std::move(forwarders_);
  }
  for (std::thread& t : threads) t.join();
  for (int fd : fds_) close(fd);
  if (listen_fd_ >= 0) close(listen_fd_);
}

std::string MetricsUrl(TestServer& server) {
  const std::regex re("metrics on http://([0-9.]+):([0-9]+)/metrics");
  for (int i = 0; i < 200; ++i) {
    std::smatch m;
    const std::string log = server.process().Stderr();
    if (std::regex_search(log, m, re)) return m[1].str() + ":" + m[2].str();
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  return "";
}

std::map<std::string, double> Scrape(const std::string& host_port) {
  std::map<std::string, double> out;
  const size_t colon = host_port.rfind(':');
  httplib::Client client(host_port.substr(0, colon), std::stoi(host_port.substr(colon + 1)));
  client.set_connection_timeout(5);
  auto res = client.Get("/metrics");
  EXPECT_TRUE(res) << "no answer from " << host_port;
  if (!res) return out;
  EXPECT_EQ(res->status, 200);
  EXPECT_TRUE(absl::StartsWith(res->get_header_value("Content-Type"), "text/plain; version=0.0.4"))
      << res->get_header_value("Content-Type");
  const std::regex sample(R"(^([a-z_]+)(\{[a-z_]+="[A-Za-z_]+"\})? (-?[0-9.e+]+)$)");
  const std::regex type(R"(^# TYPE ([a-z_]+) (counter|gauge)$)");
  std::set<std::string> typed;
  for (absl::string_view line : absl::StrSplit(res->body, '\n', absl::SkipEmpty())) {
    const std::string l(line);
    std::smatch m;
    if (absl::StartsWith(l, "# HELP ")) continue;
    if (std::regex_match(l, m, type)) {
      typed.insert(m[1].str());
      continue;
    }
    if (!std::regex_match(l, m, sample)) {
      ADD_FAILURE() << "not a sample line: " << l;
      continue;
    }
    EXPECT_TRUE(typed.count(m[1].str())) << "sample before its TYPE: " << l;
    if (absl::EndsWith(m[1].str(), "_total")) {
      EXPECT_EQ(l.find("TYPE"), std::string::npos);
    }
    out[m[1].str() + m[2].str()] = std::stod(m[3].str());
  }
  return out;
}

}  // namespace tandem::testing
