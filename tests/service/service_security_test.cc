// TLS and bearer tokens, against the real tandem-server and tandem-client binaries on
// 127.0.0.1. The certificates come from a throwaway CA made with the openssl CLI in a temp
// dir (MakeTestPki): a server certificate for IP:127.0.0.1 and DNS:localhost, and a second
// CA that did not sign it.
#include <gtest/gtest.h>
#include <signal.h>

#include <filesystem>
#include <fstream>

#include "service/bad_input_cases.h"
#include "service/service_testutil.h"
#include "tandem/codec/draco_codec.h"
#include "tandem/eval/synthetic.h"
#include "testutil/testutil.h"

namespace tandem::testing {
namespace {

constexpr char kToken1[] = "tok-Alpha-7f3a9c1e5b";
constexpr char kToken2[] = "tok-Bravo-0d4e8a2c6f";
constexpr char kWrongToken[] = "tok-Wrong-99aa00bb11";

RunResult Client(std::vector<std::string> args, const std::vector<std::string>& env = {}) {
  args.insert(args.begin(), BinPath("tandem-client"));
  return RunProcess(args, 60, env);
}

bool FinishedOk(const StreamOutcome& o) {
  return o.status.ok() && !o.responses.empty() && o.responses.back().has_final_metrics();
}

std::vector<std::string> Concat(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

std::string Port(const std::string& address) { return address.substr(address.rfind(':') + 1); }

class SecurityTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new std::string(MakeTempDir());
    auto pki = MakeTestPki(*dir_);
    ASSERT_TRUE(pki.ok()) << pki.status();
    pki_ = new TestPki(*pki);
    auto volume = WriteSyntheticVolume(*dir_, "sphere",
                                       eval::MakeSyntheticSource(eval::Shape::kSphere, 24, 24, 24));
    ASSERT_TRUE(volume.ok()) << volume.status();
    volume_ = new std::string(*volume);
    tokens_file_ = new std::string(*dir_ + "/tokens.txt");
    std::ofstream(*tokens_file_) << "# tandem tokens\n\n"
                                 << kToken1 << "\n  " << kToken2 << "  \r\n# end\n";
  }
  static void TearDownTestSuite() {
    delete dir_;
    delete pki_;
    delete volume_;
    delete tokens_file_;
    dir_ = volume_ = tokens_file_ = nullptr;
    pki_ = nullptr;
  }
  void SetUp() override {
    ASSERT_NE(pki_, nullptr);
    ASSERT_NE(volume_, nullptr);
  }
  static std::vector<std::string> TlsArgs() {
    return {"--tls-cert", pki_->server_crt, "--tls-key", pki_->server_key};
  }
  static std::vector<std::string> StreamArgs(const std::string& server, const std::string& out) {
    return {"stream", "--server", server, "--input", *volume_, "--iso",
            "0",      "--error",  "0.5",  "--out",   out};
  }
  static std::string* dir_;
  static TestPki* pki_;
  static std::string* volume_;
  static std::string* tokens_file_;
};
std::string* SecurityTest::dir_ = nullptr;
TestPki* SecurityTest::pki_ = nullptr;
std::string* SecurityTest::volume_ = nullptr;
std::string* SecurityTest::tokens_file_ = nullptr;

using TlsTest = SecurityTest;
using AuthTest = SecurityTest;

TEST_F(TlsTest, StreamHealthAndInfoWorkWithTheCa) {
  auto server = TestServer::Start(TlsArgs(), {ReadFileOrEmpty(pki_->ca_crt), ""});
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string& address = (*server)->address();
  EXPECT_EQ((*server)->Health(), "SERVING");
  EXPECT_NE((*server)->process().Stderr().find("; TLS;"), std::string::npos)
      << (*server)->process().Stderr();

  const std::string out = *dir_ + "/tls.drc";
  RunResult r = Client(Concat(StreamArgs(address, out), {"--tls-ca", pki_->ca_crt}));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto mesh = codec::DecodeDraco(ReadFileOrEmpty(out));
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_GT(mesh->num_triangles(), 0u);

  // The certificate's DNS name, and the CA from the environment.
  RunResult info =
      Client({"info", "--server", "localhost:" + Port(address)}, {"TANDEM_TLS_CA=" + pki_->ca_crt});
  ASSERT_EQ(info.exit_code, 0) << info.err;
  EXPECT_NE(info.out.find("security               TLS, no authentication"), std::string::npos)
      << info.out;
  RunResult health = Client({"health", "--server", address, "--tls-ca", pki_->ca_crt});
  EXPECT_EQ(health.exit_code, 0) << health.err;
  EXPECT_EQ(health.out, "SERVING\n");
  auto got = (*server)->Info();
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_TRUE(got->tls());
  EXPECT_FALSE(got->token_required());
}

TEST_F(TlsTest, ServerTakesItsCertificateFromTheEnvironment) {
  auto server = TestServer::Start(
      {}, {ReadFileOrEmpty(pki_->ca_crt), ""},
      {"TANDEM_TLS_CERT=" + pki_->server_crt, "TANDEM_TLS_KEY=" + pki_->server_key});
  ASSERT_TRUE(server.ok()) << server.status();
  EXPECT_EQ((*server)->Health(), "SERVING");
  auto info = (*server)->Info();
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_TRUE(info->tls());
}

TEST_F(TlsTest, PlaintextClientFailsCleanly) {
  auto server = TestServer::Start(TlsArgs(), {ReadFileOrEmpty(pki_->ca_crt), ""});
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string& address = (*server)->address();
  RunResult info = Client({"info", "--server", address, "--timeout", "10"});
  EXPECT_EQ(info.exit_code, 1) << info.err;
  EXPECT_NE(info.err.find("UNAVAILABLE"), std::string::npos) << info.err;
  EXPECT_NE(info.err.find("If it uses TLS, give --tls-ca"), std::string::npos) << info.err;
  RunResult stream = Client(StreamArgs(address, *dir_ + "/never.drc"));
  EXPECT_EQ(stream.exit_code, 1) << stream.err;
  EXPECT_NE(stream.err.find("UNAVAILABLE"), std::string::npos) << stream.err;
  EXPECT_FALSE(std::filesystem::exists(*dir_ + "/never.drc"));
  // A raw plaintext stub too: UNAVAILABLE, no hang.
  auto stub = v1::Tandem::NewStub(grpc::CreateChannel(address, grpc::InsecureChannelCredentials()));
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  v1::InfoResponse response;
  EXPECT_EQ(stub->GetInfo(&context, v1::InfoRequest(), &response).error_code(),
            grpc::StatusCode::UNAVAILABLE);
  // The server shrugs it off.
  EXPECT_EQ((*server)->Health(), "SERVING");
  v1::Counters counters;
  EXPECT_TRUE((*server)->WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_EQ(counters.sessions_started(), 0);
}

TEST_F(TlsTest, WrongCaFails) {
  auto server = TestServer::Start(TlsArgs(), {ReadFileOrEmpty(pki_->ca_crt), ""});
  ASSERT_TRUE(server.ok()) << server.status();
  RunResult r = Client(Concat(StreamArgs((*server)->address(), *dir_ + "/never.drc"),
                              {"--tls-ca", pki_->other_ca_crt}));
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_NE(r.err.find("UNAVAILABLE"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("Check --tls-ca"), std::string::npos) << r.err;
  RunResult health = Client({"health", "--server", (*server)->address(), "--tls-ca",
                             pki_->other_ca_crt, "--timeout", "10"});
  EXPECT_EQ(health.exit_code, 1) << health.err;
  // A certificate that does not name the host dialled fails the same way...
  RunResult other_name = Client({"info", "--server", (*server)->address(), "--tls-ca", pki_->ca_crt,
                                 "--tls-server-name", "tandem.example.org"});
  EXPECT_EQ(other_name.exit_code, 1) << other_name.err;
  // ... and the right name works (localhost is in the certificate).
  RunResult right_name = Client({"info", "--server", (*server)->address(), "--tls-ca", pki_->ca_crt,
                                 "--tls-server-name", "localhost"});
  EXPECT_EQ(right_name.exit_code, 0) << right_name.err;
  EXPECT_EQ((*server)->Health(), "SERVING");
}

TEST_F(TlsTest, BadTlsConfigurationStopsTheServerWithAMessage) {
  RunResult only_cert = RunProcess(
      {BinPath("tandem-server"), "--listen", "127.0.0.1:0", "--tls-cert", pki_->server_crt});
  EXPECT_EQ(only_cert.exit_code, 2);
  EXPECT_NE(only_cert.err.find("--tls-cert and --tls-key go together"), std::string::npos)
      << only_cert.err;
  RunResult missing = RunProcess({BinPath("tandem-server"), "--listen", "127.0.0.1:0", "--tls-cert",
                                  *dir_ + "/absent.crt", "--tls-key", pki_->server_key});
  EXPECT_EQ(missing.exit_code, 1);  // a file, not the command line
  EXPECT_NE(missing.err.find("absent.crt"), std::string::npos) << missing.err;
  RunResult not_pem = RunProcess({BinPath("tandem-server"), "--listen", "127.0.0.1:0", "--tls-cert",
                                  *tokens_file_, "--tls-key", pki_->server_key});
  EXPECT_EQ(not_pem.exit_code, 1);  // a file, not the command line
  EXPECT_NE(not_pem.err.find("not a PEM file"), std::string::npos) << not_pem.err;
  // The CA's key with the server's certificate: before the check, gRPC logged "Invalid
  // private key" and the server only guessed at the cause.
  RunResult wrong_key = RunProcess({BinPath("tandem-server"), "--listen", "127.0.0.1:0",
                                    "--tls-cert", pki_->server_crt, "--tls-key",
                                    *dir_ + "/ca.key"});
  EXPECT_EQ(wrong_key.exit_code, 1);  // a file, not the command line
  EXPECT_NE(wrong_key.err.find("--tls-key " + *dir_ + "/ca.key is not the private key of the "
                               "certificate in --tls-cert " + pki_->server_crt),
            std::string::npos)
      << wrong_key.err;
  RunResult cert_as_key = RunProcess({BinPath("tandem-server"), "--listen", "127.0.0.1:0",
                                      "--tls-cert", pki_->server_crt, "--tls-key",
                                      pki_->server_crt});
  EXPECT_EQ(cert_as_key.exit_code, 1);  // a file, not the command line
  EXPECT_NE(cert_as_key.err.find("no unencrypted PEM private key"), std::string::npos)
      << cert_as_key.err;
  RunResult key_as_cert = RunProcess({BinPath("tandem-server"), "--listen", "127.0.0.1:0",
                                      "--tls-cert", pki_->server_key, "--tls-key",
                                      pki_->server_key});
  EXPECT_EQ(key_as_cert.exit_code, 1);  // a file, not the command line
  EXPECT_NE(key_as_cert.err.find("no PEM certificate"), std::string::npos) << key_as_cert.err;
  RunResult bad_ca = Client({"info", "--server", "127.0.0.1:1", "--tls-ca", *tokens_file_});
  EXPECT_EQ(bad_ca.exit_code, 1);
  EXPECT_NE(bad_ca.err.find("no PEM certificate"), std::string::npos) << bad_ca.err;
}

TEST_F(AuthTest, TokenRequiredForTandemCallsButNotForHealth) {
  auto server = TestServer::Start({"--auth-tokens-file", *tokens_file_});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  auto stub = s.NewStub();

  // Health: open, through the tests' stub and the client binary.
  EXPECT_EQ(s.Health(), "SERVING");
  RunResult health = Client({"health", "--server", s.address()});
  EXPECT_EQ(health.exit_code, 0) << health.err;

  // Extract and GetInfo with no token, a wrong one, a malformed header.
  struct Attempt {
    const char* name;
    std::vector<std::pair<std::string, std::string>> metadata;
    const char* reason;
  };
  const std::vector<Attempt> attempts = {
      {"no token", {}, "no authorization metadata"},
      {"wrong token",
       {{"authorization", std::string("Bearer ") + kWrongToken}},
       "unknown bearer token"},
      {"token without scheme", {{"authorization", kToken1}}, "is not \"Bearer <token>\""},
      {"basic auth", {{"authorization", "Basic dXNlcjpwYXNz"}}, "is not \"Bearer <token>\""},
      {"two headers",
       {{"authorization", std::string("Bearer ") + kToken1},
        {"authorization", std::string("Bearer ") + kWrongToken}},
       "more than one authorization"},
  };
  for (const Attempt& a : attempts) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    for (const auto& [k, v] : a.metadata) context.AddMetadata(k, v);
    v1::InfoResponse info;
    const grpc::Status st = stub->GetInfo(&context, v1::InfoRequest(), &info);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::UNAUTHENTICATED) << a.name;
    EXPECT_NE(st.error_message().find(a.reason), std::string::npos)
        << a.name << ": " << st.error_message();
    EXPECT_NE(st.error_message().find("authorization: Bearer <token>"), std::string::npos)
        << st.error_message();

    grpc::ClientContext stream_context;
    for (const auto& [k, v] : a.metadata) stream_context.AddMetadata(k, v);
    auto stream = stub->Extract(&stream_context);
    for (const v1::ExtractRequest& r : Good()) {
      if (!stream->Write(r)) break;
    }
    stream->WritesDone();
    v1::ExtractResponse response;
    EXPECT_FALSE(stream->Read(&response)) << a.name;
    const grpc::Status extract = stream->Finish();
    EXPECT_EQ(extract.error_code(), grpc::StatusCode::UNAUTHENTICATED) << a.name;
    EXPECT_NE(extract.error_message().find(a.reason), std::string::npos) << a.name;

    // Watch too (before the id is even looked up: an unknown id says nothing).
    grpc::ClientContext watch_context;
    for (const auto& [k, v] : a.metadata) watch_context.AddMetadata(k, v);
    v1::WatchRequest watch;
    watch.set_session_id("0123456789abcdef0123456789abcdef");
    auto watcher = stub->Watch(&watch_context, watch);
    EXPECT_FALSE(watcher->Read(&response)) << a.name;
    const grpc::Status watched = watcher->Finish();
    EXPECT_EQ(watched.error_code(), grpc::StatusCode::UNAUTHENTICATED) << a.name;
    EXPECT_NE(watched.error_message().find(a.reason), std::string::npos) << a.name;
  }

  // The right tokens (either; the scheme in any case) work.
  for (const std::string& value :
       {std::string("Bearer ") + kToken1, std::string("bearer  ") + kToken2}) {
    grpc::ClientContext context;
    context.AddMetadata("authorization", value);
    v1::InfoResponse info;
    const grpc::Status st = stub->GetInfo(&context, v1::InfoRequest(), &info);
    ASSERT_TRUE(st.ok()) << st.error_message();
    EXPECT_TRUE(info.token_required());
    EXPECT_FALSE(info.tls());
  }
}

TEST_F(AuthTest, ClientSendsItsTokenAndTheLogNeverShowsOne) {
  auto server = TestServer::Start({"--auth-tokens-file", *tokens_file_}, {"", kToken2});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  const std::string out = *dir_ + "/auth.drc";

  RunResult none = Client(StreamArgs(s.address(), out));
  EXPECT_EQ(none.exit_code, 1) << none.err;
  EXPECT_NE(none.err.find("UNAUTHENTICATED"), std::string::npos) << none.err;
  EXPECT_NE(none.err.find("no token was sent"), std::string::npos) << none.err;
  RunResult wrong =
      Client(StreamArgs(s.address(), out), {std::string("TANDEM_TOKEN=") + kWrongToken});
  EXPECT_EQ(wrong.exit_code, 1) << wrong.err;
  EXPECT_NE(wrong.err.find("unknown bearer token"), std::string::npos) << wrong.err;
  EXPECT_FALSE(std::filesystem::exists(out));

  RunResult by_env = Client(StreamArgs(s.address(), out), {std::string("TANDEM_TOKEN=") + kToken1});
  EXPECT_EQ(by_env.exit_code, 0) << by_env.err;
  RunResult by_file = Client(Concat(StreamArgs(s.address(), out), {"--token-file", *tokens_file_}),
                             {std::string("TANDEM_TOKEN=") + kWrongToken});  // the file wins
  EXPECT_EQ(by_file.exit_code, 0) << by_file.err;
  RunResult by_env_file =
      Client({"info", "--server", s.address()}, {"TANDEM_TOKEN_FILE=" + *tokens_file_});
  EXPECT_EQ(by_env_file.exit_code, 0) << by_env_file.err;
  EXPECT_NE(by_env_file.out.find("plaintext, bearer token required"), std::string::npos)
      << by_env_file.out;
  RunResult info_none = Client({"info", "--server", s.address()});
  EXPECT_EQ(info_none.exit_code, 1) << info_none.err;
  EXPECT_NE(info_none.err.find("UNAUTHENTICATED"), std::string::npos) << info_none.err;

  v1::Counters counters;
  ASSERT_TRUE(s.WaitIdle(10, &counters)) << counters.ShortDebugString();
  EXPECT_EQ(counters.sessions_started(), 2) << "refused streams never became sessions";
  EXPECT_EQ(counters.unauthenticated_calls(), 3);

  s.process().Signal(SIGTERM);
  ASSERT_EQ(s.process().Wait(30), 0);
  const std::string log = s.process().Stderr();
  EXPECT_NE(log.find("refused peer=\"ipv4:127.0.0.1:"), std::string::npos) << log;
  EXPECT_NE(log.find("method=Extract status=UNAUTHENTICATED reason=\"no authorization metadata\""),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("method=GetInfo"), std::string::npos) << log;
  EXPECT_NE(log.find("reason=\"unknown bearer token\""), std::string::npos) << log;
  for (const char* token : {kToken1, kToken2, kWrongToken}) {
    EXPECT_EQ(log.find(token), std::string::npos) << "the log shows a token: " << log;
  }
  EXPECT_EQ(log.find("tok-"), std::string::npos) << log;
}

// Sessions are their creator's: with per-user tokens, a user's clients list and watch the
// user's sessions without a key; another user's token sees neither the id nor the mesh
// (NOT_FOUND, as for an unknown id) until it is given the watch key.
TEST_F(AuthTest, ASessionIsItsTokensAndTheWatchKeysOnly) {
  auto server = TestServer::Start({"--auth-tokens-file", *tokens_file_});
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string& address = (*server)->address();
  const std::string alpha = std::string("TANDEM_TOKEN=") + kToken1;
  const std::string bravo = std::string("TANDEM_TOKEN=") + kToken2;
  RunResult stream = Client(Concat(StreamArgs(address, *dir_ + "/mine.ply"), {"--seal"}), {alpha});
  ASSERT_EQ(stream.exit_code, 0) << stream.err;
  // "... TANDEM_RESUME=ID:TOKEN ..." and "... TANDEM_WATCH_KEY=KEY ..."
  auto printed = [&](const std::string& name) {
    const size_t at = stream.err.find(name + "=");
    if (at == std::string::npos) return std::string();
    return stream.err.substr(at + name.size() + 1, 32);
  };
  const std::string id = printed("TANDEM_RESUME");
  const std::string key = printed("TANDEM_WATCH_KEY");
  ASSERT_EQ(id.size(), 32u) << stream.err;
  ASSERT_EQ(key.size(), 32u) << stream.err;

  RunResult own_info = Client({"info", "--server", address}, {alpha});
  ASSERT_EQ(own_info.exit_code, 0) << own_info.err;
  EXPECT_NE(own_info.out.find("session                " + id), std::string::npos) << own_info.out;
  RunResult other_info = Client({"info", "--server", address}, {bravo});
  ASSERT_EQ(other_info.exit_code, 0) << other_info.err;
  EXPECT_EQ(other_info.out.find(id), std::string::npos) << other_info.out;
  EXPECT_NE(other_info.out.find("sessions listed        0"), std::string::npos) << other_info.out;
  RunResult keyed_info = Client({"info", "--server", address}, {bravo, "TANDEM_WATCH_KEY=" + key});
  EXPECT_NE(keyed_info.out.find("session                " + id), std::string::npos)
      << keyed_info.out;

  const std::vector<std::string> watch = {"watch", "--server", address, "--session", id, "--out"};
  RunResult own = Client(Concat(watch, {*dir_ + "/own.ply"}), {alpha});
  ASSERT_EQ(own.exit_code, 0) << own.err;
  EXPECT_EQ(ReadFileOrEmpty(*dir_ + "/own.ply"), ReadFileOrEmpty(*dir_ + "/mine.ply"));
  RunResult other = Client(Concat(watch, {*dir_ + "/other.ply"}), {bravo});
  EXPECT_EQ(other.exit_code, 1) << other.err;
  EXPECT_NE(other.err.find("NOT_FOUND: no session '" + id + "' that this call may watch"),
            std::string::npos)
      << other.err;
  EXPECT_FALSE(std::filesystem::exists(*dir_ + "/other.ply"));
  RunResult shared =
      Client(Concat(watch, {*dir_ + "/shared.ply"}), {bravo, "TANDEM_WATCH_KEY=" + key});
  ASSERT_EQ(shared.exit_code, 0) << shared.err;
  EXPECT_EQ(ReadFileOrEmpty(*dir_ + "/shared.ply"), ReadFileOrEmpty(*dir_ + "/mine.ply"));
}

TEST_F(AuthTest, TokensOverTls) {
  auto server = TestServer::Start(Concat(TlsArgs(), {"--auth-tokens-file", *tokens_file_}),
                                  {ReadFileOrEmpty(pki_->ca_crt), kToken1});
  ASSERT_TRUE(server.ok()) << server.status();
  TestServer& s = **server;
  EXPECT_EQ(s.Health(), "SERVING") << "no token needed for health over TLS either";
  EXPECT_TRUE(FinishedOk(RunStream(*s.NewStub(), Good(), &s)));
  const std::string out = *dir_ + "/both.drc";
  RunResult r = Client(Concat(StreamArgs(s.address(), out), {"--tls-ca", pki_->ca_crt}),
                       {std::string("TANDEM_TOKEN=") + kToken2});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  RunResult no_token = Client(Concat(StreamArgs(s.address(), out), {"--tls-ca", pki_->ca_crt}));
  EXPECT_EQ(no_token.exit_code, 1) << no_token.err;
  EXPECT_NE(no_token.err.find("UNAUTHENTICATED"), std::string::npos) << no_token.err;
  auto info = s.Info();
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_TRUE(info->tls());
  EXPECT_TRUE(info->token_required());
  EXPECT_EQ(s.process().Stderr().find("tok-"), std::string::npos) << s.process().Stderr();
}

TEST_F(AuthTest, BadTokensFileStopsTheServer) {
  const std::string empty = *dir_ + "/empty_tokens.txt";
  std::ofstream(empty) << "# no tokens yet\n\n";
  RunResult r = RunProcess(
      {BinPath("tandem-server"), "--listen", "127.0.0.1:0", "--auth-tokens-file", empty});
  EXPECT_EQ(r.exit_code, 1);  // the file's content
  EXPECT_NE(r.err.find("no token in the file"), std::string::npos) << r.err;
  RunResult missing = RunProcess({BinPath("tandem-server"), "--listen", "127.0.0.1:0"}, 60,
                                 {"TANDEM_AUTH_TOKENS_FILE=" + *dir_ + "/absent_tokens.txt"});
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_NE(missing.err.find("absent_tokens.txt"), std::string::npos) << missing.err;
}

}  // namespace
}  // namespace tandem::testing
