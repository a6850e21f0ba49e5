#include "tandem/server/tls_check.h"

#include <openssl/bio.h>
#include <openssl/err.h>
#include <openssl/evp.h>
#include <openssl/pem.h>
#include <openssl/x509.h>

#include <memory>

#include "absl/strings/str_cat.h"

namespace tandem::server {
namespace {

struct BioFree {
  void operator()(BIO* b) const { BIO_free(b); }
};
struct X509Free {
  void operator()(X509* x) const { X509_free(x); }
};
struct KeyFree {
  void operator()(EVP_PKEY* k) const { EVP_PKEY_free(k); }
};

// OpenSSL's reason for the last error, then clears the queue.
std::string LastError() {
  const unsigned long e = ERR_peek_last_error();
  ERR_clear_error();
  const char* reason = e != 0 ? ERR_reason_error_string(e) : nullptr;
  return reason != nullptr ? reason : "no reason given";
}

std::unique_ptr<BIO, BioFree> Reader(const std::string& text) {
  return std::unique_ptr<BIO, BioFree>(BIO_new_mem_buf(text.data(), static_cast<int>(text.size())));
}

}  // namespace

absl::Status CheckCertificateAndKey(const std::string& cert_pem, const std::string& key_pem,
                                    const std::string& cert_name, const std::string& key_name) {
  ERR_clear_error();
  auto cert_bio = Reader(cert_pem);
  std::unique_ptr<X509, X509Free> cert(
      PEM_read_bio_X509(cert_bio.get(), nullptr, nullptr, nullptr));
  if (!cert) {
    return absl::InvalidArgumentError(absl::StrCat(
        "--tls-cert ", cert_name, ": no PEM certificate in it (", LastError(), ")"));
  }
  auto key_bio = Reader(key_pem);
  // No passphrase callback: an encrypted key fails here rather than prompting.
  static constexpr auto kNoPassphrase = +[](char*, int, int, void*) { return 0; };
  std::unique_ptr<EVP_PKEY, KeyFree> key(
      PEM_read_bio_PrivateKey(key_bio.get(), nullptr, kNoPassphrase, nullptr));
  if (!key) {
    return absl::InvalidArgumentError(absl::StrCat(
        "--tls-key ", key_name, ": no unencrypted PEM private key in it (", LastError(), ")"));
  }
  if (X509_check_private_key(cert.get(), key.get()) != 1) {
    ERR_clear_error();
    return absl::InvalidArgumentError(absl::StrCat(
        "--tls-key ", key_name, " is not the private key of the certificate in --tls-cert ",
        cert_name, " (the first certificate of the file must be the server's own)"));
  }
  return absl::OkStatus();
}

}  // namespace tandem::server
