//! The client end of a connection to the coordinator, shared by
//! `trevi-worker` and `trevi-submit`: `http://` is plain gRPC, `https://` is
//! gRPC over TLS (rustls), trusting either the CA certificate the user names
//! (a self-signed local farm) or the system's and the webpki roots.

use std::path::{Path, PathBuf};
use tonic::transport::{Certificate, ClientTlsConfig, Endpoint};

/// TLS settings of a client. Both fields are optional; with neither, an
/// `https://` coordinator must present a certificate that the system roots
/// (or the Mozilla roots built in) trust, for the URL's host name.
#[derive(Debug, Clone, Default)]
pub struct ClientTls {
    /// A PEM file of the CA certificate(s) to trust instead of the usual
    /// roots (`--tls-ca`).
    pub ca_file: Option<PathBuf>,
    /// The name the coordinator's certificate must carry, when it is not the
    /// URL's host (`--tls-domain`), e.g. connecting by IP address.
    pub domain: Option<String>,
}

/// Why an endpoint could not be built.
#[derive(Debug, thiserror::Error)]
pub enum EndpointError {
    /// The address is not a URI tonic accepts.
    #[error("bad coordinator address \"{url}\": {reason}")]
    BadAddress {
        /// The address as given.
        url: String,
        /// tonic's error, with its causes ([`error_chain`]).
        reason: String,
    },
    /// The address has no scheme, or one other than `http` and `https`
    /// (the address as given).
    #[error("bad coordinator address \"{0}\": it must start with http:// or https://")]
    Scheme(String),
    /// A TLS option (`--tls-ca` or `--tls-domain`) was given for a plain
    /// `http://` address, where it would be silently ignored.
    #[error(
        "{option} is only for TLS, but the coordinator address \"{url}\" is plain http://; \
         use https://"
    )]
    TlsOptionWithoutHttps {
        /// The option's command-line name.
        option: &'static str,
        /// The address as given.
        url: String,
    },
    /// The `--tls-ca` file could not be read.
    #[error("cannot read the CA certificate {path}: {source}")]
    ReadCa {
        /// The file named by [`ClientTls::ca_file`].
        path: PathBuf,
        /// Why reading it failed.
        source: std::io::Error,
    },
    /// The `--tls-ca` file was read but has no PEM certificate block (its
    /// path).
    #[error(
        "the CA certificate file {0} holds no PEM certificate \
         (no \"-----BEGIN CERTIFICATE-----\" block)"
    )]
    NoCertificate(PathBuf),
    /// tonic refused the TLS settings for this address.
    #[error("cannot set up TLS for \"{url}\": {reason}")]
    Tls {
        /// The address as given.
        url: String,
        /// tonic's error, with its causes ([`error_chain`]).
        reason: String,
    },
}

/// An endpoint for the coordinator at `url` (`http://HOST:PORT` or
/// `https://HOST:PORT`), with TLS set up for `https://`. Callers add their
/// own timeouts and connect.
pub fn endpoint(url: &str, tls: &ClientTls) -> Result<Endpoint, EndpointError> {
    let endpoint =
        Endpoint::from_shared(url.to_string()).map_err(|e| EndpointError::BadAddress {
            url: url.to_string(),
            reason: error_chain(&e),
        })?;
    let scheme = endpoint.uri().scheme_str().map(str::to_ascii_lowercase);
    match scheme.as_deref() {
        Some("http") => {
            let option = if tls.ca_file.is_some() {
                Some("--tls-ca")
            } else if tls.domain.is_some() {
                Some("--tls-domain")
            } else {
                None
            };
            match option {
                Some(option) => Err(EndpointError::TlsOptionWithoutHttps {
                    option,
                    url: url.to_string(),
                }),
                None => Ok(endpoint),
            }
        }
        Some("https") => {
            let mut config = ClientTlsConfig::new();
            config = match &tls.ca_file {
                Some(path) => config.ca_certificate(read_ca(path)?),
                None => config.with_enabled_roots(),
            };
            if let Some(domain) = &tls.domain {
                config = config.domain_name(domain.clone());
            }
            endpoint.tls_config(config).map_err(|e| EndpointError::Tls {
                url: url.to_string(),
                reason: error_chain(&e),
            })
        }
        _ => Err(EndpointError::Scheme(url.to_string())),
    }
}

fn read_ca(path: &Path) -> Result<Certificate, EndpointError> {
    let pem = std::fs::read(path).map_err(|source| EndpointError::ReadCa {
        path: path.to_path_buf(),
        source,
    })?;
    if !contains(&pem, b"-----BEGIN CERTIFICATE-----") {
        return Err(EndpointError::NoCertificate(path.to_path_buf()));
    }
    Ok(Certificate::from_pem(pem))
}

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

/// An error and its sources on one line (`a: b: c`), skipping a source whose
/// text is already there (tonic and tokio-rustls repeat their causes).
/// tonic's transport errors say only "transport error" at the top; the cause
/// (refused connection, unknown certificate issuer, …) is further down.
pub fn error_chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut out = e.to_string();
    let mut next = e.source();
    while let Some(s) = next {
        let text = s.to_string();
        if !text.is_empty() && !out.contains(&text) {
            out.push_str(": ");
            out.push_str(&text);
        }
        next = s.source();
    }
    out
}

/// What to do about an error seen talking to the coordinator at `url`, when
/// its text (with its causes, see [`error_chain`]) shows a TLS mismatch.
///
/// A plain `http://` client against a TLS coordinator sees only a broken
/// connection (how it breaks depends on timing), so for a transport failure
/// on an `http://` URL this asks the server once with [`serves_tls`]: it
/// blocks for up to a few seconds.
pub fn hint(url: &str, error: &str) -> Option<&'static str> {
    let https = url
        .get(..8)
        .is_some_and(|s| s.eq_ignore_ascii_case("https://"));
    let broken = [
        "frame with invalid size",
        "h2 protocol error",
        "broken pipe",
        "connection reset",
        "transport error",
    ]
    .iter()
    .any(|m| error.contains(m));
    if !https && broken && serves_tls(url) {
        Some("the coordinator seems to serve TLS: use an https:// URL (and --tls-ca if the farm has its own CA)")
    } else if https && error.contains("invalid peer certificate") {
        Some(
            "the coordinator's certificate is not trusted, or not for this name: give the farm's CA \
             certificate with --tls-ca (ca.pem of deploy/make-certs.sh) and use a host name the \
             certificate was made for (or --tls-domain NAME)",
        )
    } else if https && (error.contains("InvalidContentType") || error.contains("corrupt message")) {
        Some("the coordinator seems to serve plain gRPC (no --tls-cert): use an http:// URL")
    } else {
        None
    }
}

/// Whether the server of an `http://` URL serves TLS: it answers the HTTP/2
/// connection preface with a TLS alert record (content type 21, version 3.x)
/// where a gRPC server would send HTTP/2 settings. Blocking, at most about
/// two seconds per step; `false` when it cannot tell.
pub fn serves_tls(url: &str) -> bool {
    use std::io::{Read, Write};
    use std::net::ToSocketAddrs;
    const PREFACE: &[u8] = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n";
    let timeout = std::time::Duration::from_secs(2);
    let Ok(uri) = url.parse::<tonic::codegen::http::Uri>() else {
        return false;
    };
    let Some(host) = uri.host() else {
        return false;
    };
    let host = host.trim_start_matches('[').trim_end_matches(']');
    let port = uri.port_u16().unwrap_or(80);
    let Some(addr) = (host, port)
        .to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
    else {
        return false;
    };
    let Ok(mut conn) = std::net::TcpStream::connect_timeout(&addr, timeout) else {
        return false;
    };
    let _ = conn.set_read_timeout(Some(timeout));
    let _ = conn.set_write_timeout(Some(timeout));
    if conn.write_all(PREFACE).is_err() {
        return false;
    }
    let mut head = [0u8; 2];
    conn.read_exact(&mut head).is_ok() && head == [0x15, 0x03]
}

/// Whether a connection failed because the coordinator's certificate was not
/// trusted or did not match (retrying will not help), as opposed to the
/// coordinator being away.
pub fn is_certificate_error(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut next = Some(e);
    while let Some(s) = next {
        if let Some(r) = s.downcast_ref::<rustls::Error>() {
            return matches!(
                r,
                rustls::Error::InvalidCertificate(_) | rustls::Error::NoCertificatesPresented
            );
        }
        if let Some(io) = s.downcast_ref::<std::io::Error>() {
            if let Some(r) = io.get_ref().and_then(|i| i.downcast_ref::<rustls::Error>()) {
                return matches!(
                    r,
                    rustls::Error::InvalidCertificate(_) | rustls::Error::NoCertificatesPresented
                );
            }
        }
        next = s.source();
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_http_needs_no_tls_options() {
        assert!(endpoint("http://127.0.0.1:1", &ClientTls::default()).is_ok());
        let e = endpoint(
            "http://127.0.0.1:1",
            &ClientTls {
                ca_file: Some("ca.pem".into()),
                domain: None,
            },
        )
        .unwrap_err();
        assert!(
            matches!(
                e,
                EndpointError::TlsOptionWithoutHttps {
                    option: "--tls-ca",
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn bad_scheme_and_ca_files_are_named() {
        let e = endpoint("ftp://host:1", &ClientTls::default()).unwrap_err();
        assert!(matches!(e, EndpointError::Scheme(_)), "{e}");
        let e = endpoint(
            "https://localhost:1",
            &ClientTls {
                ca_file: Some("/nonexistent/ca.pem".into()),
                domain: None,
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("/nonexistent/ca.pem"), "{e}");
        let dir = std::env::temp_dir().join(format!("trevi-proto-ca-{}", std::process::id()));
        std::fs::write(&dir, "not a certificate").unwrap();
        let e = endpoint(
            "https://localhost:1",
            &ClientTls {
                ca_file: Some(dir.clone()),
                domain: None,
            },
        )
        .unwrap_err();
        let _ = std::fs::remove_file(&dir);
        assert!(matches!(e, EndpointError::NoCertificate(_)), "{e}");
    }

    #[test]
    fn hints_only_for_tls_mismatches() {
        assert!(
            hint("https://h:1", "invalid peer certificate: UnknownIssuer")
                .unwrap()
                .contains("--tls-ca")
        );
        assert!(hint(
            "HTTPS://h:1",
            "received corrupt message of type InvalidContentType"
        )
        .unwrap()
        .contains("http://"));
        assert_eq!(hint("http://h:1", "connection refused"), None);
        // Nothing listens on port 1: no TLS there.
        assert_eq!(hint("http://127.0.0.1:1", "transport error"), None);
        assert_eq!(hint("https://h:1", "frame with invalid size"), None);
    }

    #[test]
    fn https_uses_the_built_in_roots_without_a_ca() {
        assert!(endpoint("https://localhost:1", &ClientTls::default()).is_ok());
    }
}
