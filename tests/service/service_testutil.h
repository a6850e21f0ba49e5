// Helpers of the service tests: child processes with bounded waits, a tandem-server child
// on 127.0.0.1 with an ephemeral port, request builders, and mesh comparisons that allow
// for Draco's quantization and reordering.
#ifndef TANDEM_TESTS_SERVICE_SERVICE_TESTUTIL_H_
#define TANDEM_TESTS_SERVICE_SERVICE_TESTUTIL_H_

#include <sys/types.h>

#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <thread>
#include <optional>
#include <string>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "absl/status/statusor.h"
#include "tandem/mesh.h"
#include "tandem/tandem.h"
#include "tandem/v1/tandem.grpc.pb.h"
#include "tandem/volume.h"
#include "testutil/testutil.h"  // ResidentBytes, kSanitized

namespace tandem::testing {

// A child process whose stdout and stderr go to files in `dir`. The destructor kills
// (SIGKILL) and reaps it if it is still running.
class ChildProcess {
 public:
  // `env`: NAME=VALUE entries added to (or replacing in) this process's environment.
  static absl::StatusOr<std::unique_ptr<ChildProcess>> Spawn(const std::vector<std::string>& argv,
                                                             const std::string& dir,
                                                             const std::vector<std::string>& env = {});
  ~ChildProcess();
  pid_t pid() const { return pid_; }
  void Signal(int sig) const;
  // Exit code (128 + signal number if killed), or nullopt if still running at the timeout.
  std::optional<int> Wait(double timeout_s);
  std::string Stdout() const;
  std::string Stderr() const;
  // Minor page faults of the process (getrusage's ru_minflt), once Wait has seen it exit.
  int64_t minor_faults() const { return minor_faults_; }

 private:
  pid_t pid_ = -1;
  std::optional<int> exit_code_;
  int64_t minor_faults_ = -1;
  std::string out_path_, err_path_;
};

struct RunResult {
  int exit_code = -1;  // -1: killed at the timeout
  std::string out, err;
  int64_t minor_faults = -1;  // of the process, when it exited
};
// Runs a program to completion (killed after timeout_s).
RunResult RunProcess(const std::vector<std::string>& argv, double timeout_s = 60,
                     const std::vector<std::string>& env = {});

// How the tests' own gRPC clients reach a TestServer.
struct ClientAuth {
  std::string ca_pem;  // "" = plaintext
  std::string token;   // "" = none
};

// build/bin/tandem-server --listen 127.0.0.1:0 [extra...], port read from its stdout.
class TestServer {
 public:
  static absl::StatusOr<std::unique_ptr<TestServer>> Start(
      const std::vector<std::string>& extra_args = {}, const ClientAuth& auth = {},
      const std::vector<std::string>& env = {});
  const std::string& address() const { return address_; }
  ChildProcess& process() { return *process_; }
  const ClientAuth& auth() const { return auth_; }
  std::shared_ptr<grpc::ChannelCredentials> Credentials() const;
  // A stub with this server's credentials; add the token with AddToken.
  std::unique_ptr<v1::Tandem::Stub> NewStub() const;
  void AddToken(grpc::ClientContext* context) const;
  // GetInfo with this server's token; `watch_keys` list those sessions too.
  absl::StatusOr<v1::InfoResponse> Info(const std::vector<std::string>& watch_keys = {}) const;
  // "SERVING", "NOT_SERVING", ... or the RPC error's code name, for health service
  // `service` ("" = the server as a whole).
  std::string Health(const std::string& service = "") const;
  // Polls GetInfo until no session, worker thread or session memory is left.
  bool WaitIdle(double timeout_s, v1::Counters* last = nullptr) const;

 private:
  std::unique_ptr<ChildProcess> process_;
  std::string address_;
  ClientAuth auth_;
};

// A TCP forwarder on 127.0.0.1 (ephemeral port) to 127.0.0.1:`target_port`, one thread
// per connection, so that a test can cut every connection under a running stream (the
// way a network failure or a restarting proxy would) while new ones keep working.
class TcpProxy {
 public:
  static absl::StatusOr<std::unique_ptr<TcpProxy>> Start(int target_port);
  ~TcpProxy();
  std::string address() const;
  // Shuts down both sockets of every open connection (the peers see them reset/closed).
  // Returns how many were open.
  int CutAll();
  int64_t bytes_forwarded() const { return bytes_.load(); }

 private:
  TcpProxy() = default;
  void AcceptLoop();
  void Forward(int from, int to);
  int listen_fd_ = -1, port_ = 0, target_port_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<int64_t> bytes_{0};
  std::thread acceptor_;
  std::mutex mu_;
  std::vector<int> fds_;  // every open socket, both sides
  std::vector<std::thread> forwarders_;
};

// A throwaway PKI made with the openssl CLI in `dir`: a CA, a server certificate signed by
// it for IP:127.0.0.1 and DNS:localhost, and a second, unrelated CA.
struct TestPki {
  std::string ca_crt, server_crt, server_key, other_ca_crt;
};
absl::StatusOr<TestPki> MakeTestPki(const std::string& dir);
std::string ReadFileOrEmpty(const std::string& path);

// "HOST:PORT" of the metrics endpoint a server started with --metrics-listen logged, once it
// has ("" after 5 s).
std::string MetricsUrl(TestServer& server);
// GET /metrics: sample name (with labels) → value; fails the test on a line that is not valid
// text exposition (HELP/TYPE comments before each family's samples).
std::map<std::string, double> Scrape(const std::string& host_port);

// Writes the first `nz` slices of a synthetic float32 field as DIR/NAME.json + .raw.
absl::StatusOr<std::string> WriteSyntheticVolume(const std::string& dir, const std::string& name,
                                                 std::unique_ptr<SliceSource> source);

// The volume the load, kill and concurrency tests stream, generated so that a clone without
// ../shared runs them: the Link (two interlocked tori) on the shared head CT's grid,
// 64 x 64 x 93, float32, as DIR/load.json. Stream it with --iso kLoadIso --error kLoadError.
absl::StatusOr<std::string> WriteLoadVolume(const std::string& dir);

// Voxels no scan has, each making every layer a dense surface: most cubes crossed, two to
// four triangles a voxel, about 300 bytes a voxel once in a session's store and queues.
enum class Pattern {
  kNoise,         // uniform random bytes, iso at the median
  kCheckerboard,  // 0 and 255 alternating along every axis
  kNoisyField,    // a smooth field under strong noise, iso at its mean: no malice needed
};
// An n x n x nz uint8 volume of `pattern` (the same bytes every time) as DIR/patternP.json;
// *iso: the iso-value where it is hardest.
absl::StatusOr<std::string> WritePattern(const std::string& dir, Pattern pattern, int64_t n,
                                         int64_t nz, double* iso);
inline constexpr char kLoadIso[] = "0";
inline constexpr char kLoadError[] = "0.05";

// Runs a volume file through a local TandemSession (the reference the service must match).
absl::StatusOr<std::unique_ptr<TandemSession>> RunLocal(const std::string& path,
                                                        const SessionOptions& options);

// Maps every vertex of `b` to a vertex of `a` within `tol` (per coordinate), one to one.
// Returns the map (b index → a index) or an error naming the first vertex that failed.
absl::StatusOr<std::vector<uint32_t>> MatchVertices(const IndexedMesh& a, const IndexedMesh& b,
                                                    double tol);
// Same triangles (as vertex triples up to rotation, orientation kept) once b's vertices
// are renamed through `map`.
bool SameTriangles(const IndexedMesh& a, const IndexedMesh& b, const std::vector<uint32_t>& map);

// The request stream of a whole volume: config (with `config` as the template for
// options), chunks of `chunk_bytes`, End.
std::vector<v1::ExtractRequest> VolumeRequests(SliceSource& source,
                                               const v1::SessionConfig& config,
                                               size_t chunk_bytes);

struct StreamOutcome {
  grpc::Status status;
  std::vector<v1::ExtractResponse> responses;
  std::map<std::string, std::string> trailers;  // the server's trailing metadata
};
// Sends `requests` on one Extract stream (stopping at the first failed write), then
// WritesDone, then reads everything (deadline 60 s).
StreamOutcome RunStream(v1::Tandem::Stub& stub, const std::vector<v1::ExtractRequest>& requests,
                        const TestServer* server = nullptr);

}  // namespace tandem::testing

#endif  // TANDEM_TESTS_SERVICE_SERVICE_TESTUTIL_H_
