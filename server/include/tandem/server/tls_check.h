// Checks a TLS certificate and private key before gRPC gets them: gRPC only logs
// "Invalid private key" / "Handshaker factory creation failed" and refuses to listen,
// which does not say which file is wrong. OpenSSL (the library gRPC itself uses on
// Debian) reads both PEM texts and checks that the key is the certificate's.
#ifndef TANDEM_SERVER_TLS_CHECK_H_
#define TANDEM_SERVER_TLS_CHECK_H_

#include <string>

#include "absl/status/status.h"

namespace tandem::server {

// OK when `cert_pem` holds a certificate, `key_pem` a private key, and the key belongs to
// the certificate (the first certificate of a chain). Otherwise INVALID_ARGUMENT naming
// `cert_name` / `key_name` (the file names) and what is wrong.
absl::Status CheckCertificateAndKey(const std::string& cert_pem, const std::string& key_pem,
                                    const std::string& cert_name, const std::string& key_name);

}  // namespace tandem::server

#endif  // TANDEM_SERVER_TLS_CHECK_H_
