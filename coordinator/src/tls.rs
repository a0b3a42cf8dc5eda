//! TLS for the coordinator: the certificate chain and private key it serves
//! (`--tls-cert`, `--tls-key`), loaded and checked before the port opens so
//! that a wrong file is reported by name at start, not at the first client.

use std::path::{Path, PathBuf};
use tonic::transport::{Identity, ServerTlsConfig};

/// Why the coordinator's certificate or key cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// Only one of `--tls-cert` and `--tls-key` was given (the missing
    /// flag's name).
    #[error("--tls-cert and --tls-key go together: {0} is missing")]
    Half(&'static str),
    /// A file could not be read.
    #[error("cannot read the TLS {what} {path}: {source}")]
    Read {
        /// `"certificate"` or `"key"`.
        what: &'static str,
        /// The file given.
        path: PathBuf,
        /// Why reading it failed.
        source: std::io::Error,
    },
    /// The `--tls-cert` file (given) has no PEM certificate block.
    #[error(
        "the TLS certificate file {0} holds no PEM certificate \
         (no \"-----BEGIN CERTIFICATE-----\" block)"
    )]
    NoCertificate(PathBuf),
    /// The `--tls-key` file (given) has no PEM private key block.
    #[error(
        "the TLS key file {0} holds no PEM private key \
         (no \"-----BEGIN ... PRIVATE KEY-----\" block)"
    )]
    NoKey(PathBuf),
    /// rustls refused the pair: a malformed certificate or key, or a key
    /// that is not the certificate's.
    #[error("the TLS certificate {cert} and key {key} cannot be used together: {reason}")]
    Unusable {
        /// The certificate file.
        cert: PathBuf,
        /// The key file.
        key: PathBuf,
        /// rustls' or tonic's error, with its causes.
        reason: String,
    },
}

/// The server TLS configuration for `--tls-cert`/`--tls-key`: `None` when
/// neither is given (plain gRPC), an error when only one is.
pub fn server_tls(
    cert: Option<&Path>,
    key: Option<&Path>,
) -> Result<Option<ServerTlsConfig>, TlsError> {
    match (cert, key) {
        (None, None) => Ok(None),
        (Some(_), None) => Err(TlsError::Half("--tls-key")),
        (None, Some(_)) => Err(TlsError::Half("--tls-cert")),
        (Some(cert), Some(key)) => load(cert, key).map(Some),
    }
}

/// Reads a PEM certificate chain (the server's certificate first) and its
/// PEM private key (PKCS#8, PKCS#1 or SEC1), and checks that rustls accepts
/// them together.
pub fn load(cert: &Path, key: &Path) -> Result<ServerTlsConfig, TlsError> {
    let read = |what, path: &Path| {
        std::fs::read(path).map_err(|source| TlsError::Read {
            what,
            path: path.to_path_buf(),
            source,
        })
    };
    let cert_pem = read("certificate", cert)?;
    let key_pem = read("key", key)?;
    if !contains(&cert_pem, b"-----BEGIN CERTIFICATE-----") {
        return Err(TlsError::NoCertificate(cert.to_path_buf()));
    }
    if !contains(&key_pem, b"PRIVATE KEY-----") {
        return Err(TlsError::NoKey(key.to_path_buf()));
    }
    let config = ServerTlsConfig::new().identity(Identity::from_pem(cert_pem, key_pem));
    // Building the acceptor parses both files and checks that the key is the
    // certificate's: do it now, with the file names at hand.
    tonic::transport::Server::builder()
        .tls_config(config.clone())
        .map_err(|e| TlsError::Unusable {
            cert: cert.to_path_buf(),
            key: key.to_path_buf(),
            reason: trevi_proto::connect::error_chain(&e),
        })?;
    Ok(config)
}

/// A TLS acceptor for the HTTP monitor with the same certificate and key
/// (checked already by [`load`]), speaking HTTP/1.1.
pub fn https_acceptor(cert: &Path, key: &Path) -> Result<tokio_rustls::TlsAcceptor, TlsError> {
    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::{CertificateDer, PrivateKeyDer};
    let unusable = |reason: String| TlsError::Unusable {
        cert: cert.to_path_buf(),
        key: key.to_path_buf(),
        reason,
    };
    let certs = CertificateDer::pem_file_iter(cert)
        .and_then(|it| it.collect::<Result<Vec<_>, _>>())
        .map_err(|e| unusable(e.to_string()))?;
    let key_der = PrivateKeyDer::from_pem_file(key).map_err(|e| unusable(e.to_string()))?;
    let provider = std::sync::Arc::new(rustls::crypto::ring::default_provider());
    let mut config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| unusable(e.to_string()))?
        .with_no_client_auth()
        .with_single_cert(certs, key_der)
        .map_err(|e| unusable(e.to_string()))?;
    config.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(tokio_rustls::TlsAcceptor::from(std::sync::Arc::new(config)))
}

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_or_neither() {
        assert!(server_tls(None, None).unwrap().is_none());
        let e = server_tls(Some(Path::new("c.pem")), None).unwrap_err();
        assert!(matches!(e, TlsError::Half("--tls-key")), "{e}");
        let e = server_tls(None, Some(Path::new("k.pem"))).unwrap_err();
        assert!(matches!(e, TlsError::Half("--tls-cert")), "{e}");
    }

    #[test]
    fn unreadable_and_wrong_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let cert = dir.path().join("cert.pem");
        let key = dir.path().join("key.pem");
        let e = load(&cert, &key).unwrap_err();
        assert!(
            matches!(
                e,
                TlsError::Read {
                    what: "certificate",
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("cert.pem"), "{e}");

        std::fs::write(&cert, "hello").unwrap();
        std::fs::write(&key, "hello").unwrap();
        let e = load(&cert, &key).unwrap_err();
        assert!(matches!(e, TlsError::NoCertificate(_)), "{e}");

        std::fs::write(
            &cert,
            "-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n",
        )
        .unwrap();
        let e = load(&cert, &key).unwrap_err();
        assert!(matches!(e, TlsError::NoKey(_)), "{e}");

        std::fs::write(
            &key,
            "-----BEGIN PRIVATE KEY-----\nAAAA\n-----END PRIVATE KEY-----\n",
        )
        .unwrap();
        let e = load(&cert, &key).unwrap_err();
        assert!(matches!(e, TlsError::Unusable { .. }), "{e}");
    }
}
