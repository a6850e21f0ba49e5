#include "tandem/client/connection.h"

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

#include "absl/strings/str_cat.h"
#include "tandem/common/tokens.h"
#include "tandem/status_macros.h"

namespace tandem::client {

absl::StatusOr<std::string> ServiceConfigJson(const ConnectionOptions& options) {
  if (options.lb_policy != "pick_first" && options.lb_policy != "round_robin") {
    return absl::InvalidArgumentError(absl::StrCat(
        "--lb: expected pick_first or round_robin, got \"", options.lb_policy, "\""));
  }
  if (options.retries < 0 || options.retries > 4) {
    return absl::InvalidArgumentError(
        absl::StrCat("--retries: expected 0 to 4 (gRPC allows 5 attempts), got ",
                     options.retries));
  }
  // Retries are the stream client's own (StreamVolume): gRPC's retry policy replays only
  // what fits its 256 KiB buffer (one large slice commits the call), and in gRPC 1.51 a
  // retried stream was seen to hang under load.
  return absl::StrCat(R"({"loadBalancingConfig":[{")", options.lb_policy, R"(":{}}]})");
}

absl::StatusOr<std::shared_ptr<grpc::Channel>> MakeChannel(const ConnectionOptions& options) {
  std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::InsecureChannelCredentials();
  grpc::ChannelArguments args;
  TANDEM_ASSIGN_OR_RETURN(std::string service_config, ServiceConfigJson(options));
  args.SetServiceConfigJSON(service_config);
  if (options.uses_tls()) {
    grpc::SslCredentialsOptions
        ssl;  // empty roots = the system's (or GRPC_DEFAULT_SSL_ROOTS_FILE_PATH)
    if (!options.tls_ca_file.empty()) {
      std::ifstream in(options.tls_ca_file, std::ios::binary);
      if (!in) {
        return absl::NotFoundError(absl::StrCat("--tls-ca ", options.tls_ca_file, ": cannot open (",
                                                std::strerror(errno), ")"));
      }
      std::stringstream ss;
      ss << in.rdbuf();
      ssl.pem_root_certs = ss.str();
      if (ssl.pem_root_certs.find("-----BEGIN CERTIFICATE-----") == std::string::npos) {
        return absl::InvalidArgumentError(
            absl::StrCat("--tls-ca ", options.tls_ca_file, ": no PEM certificate in the file"));
      }
    }
    credentials = grpc::SslCredentials(ssl);
    if (!options.tls_server_name.empty()) {
      args.SetSslTargetNameOverride(options.tls_server_name);
    }
  }
  if (options.max_receive_bytes > 0) args.SetMaxReceiveMessageSize(options.max_receive_bytes);
  if (options.keepalive_time_ms > 0) {
    args.SetInt(GRPC_ARG_KEEPALIVE_TIME_MS, static_cast<int>(options.keepalive_time_ms));
    args.SetInt(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, 20000);
  }
  return grpc::CreateCustomChannel(options.server, credentials, args);
}

void AddToken(const ConnectionOptions& options, grpc::ClientContext* context) {
  // Plain metadata rather than grpc::AccessTokenCredentials: gRPC only attaches call
  // credentials on TLS channels, and tokens must also work through a TLS-terminating
  // proxy on a trusted network.
  if (!options.token.empty()) context->AddMetadata("authorization", "Bearer " + options.token);
}

absl::StatusOr<std::string> LoadToken(const std::string& token_file) {
  if (!token_file.empty()) {
    absl::StatusOr<std::vector<std::string>> tokens = common::ReadTokensFile(token_file);
    if (!tokens.ok()) {
      return absl::Status(tokens.status().code(),
                          absl::StrCat("--token-file: ", std::string(tokens.status().message())));
    }
    if (tokens->empty()) {
      return absl::InvalidArgumentError(
          absl::StrCat("--token-file ", token_file, ": no token in the file"));
    }
    return tokens->front();
  }
  const char* env = std::getenv("TANDEM_TOKEN");
  if (env == nullptr || *env == '\0') return std::string();
  TANDEM_ASSIGN_OR_RETURN(std::vector<std::string> tokens,
                          common::ParseTokens(env, "$TANDEM_TOKEN"));
  if (tokens.size() != 1) {
    return absl::InvalidArgumentError("$TANDEM_TOKEN: give exactly one token");
  }
  return tokens.front();
}

std::string ConnectionHint(const ConnectionOptions& options, const absl::Status& status) {
  if (absl::IsUnauthenticated(status)) {
    return options.token.empty() ? "no token was sent"
                                 : "a token was sent (--token-file or TANDEM_TOKEN) and refused";
  }
  if (absl::IsUnavailable(status) || absl::IsDeadlineExceeded(status)) {
    if (options.uses_tls()) {
      return "is tandem-server running there, with TLS? Check --tls-ca and that the certificate "
             "names the host you dial (or --tls-server-name)";
    }
    return "is tandem-server running there? If it uses TLS, give --tls-ca";
  }
  return "";
}

}  // namespace tandem::client
