//! The POST of one event to one URL: a connection per delivery (events are
//! few: a handful per job), HTTP/1.1 through hyper's client connection, and
//! for `https://` rustls with the Mozilla roots of `webpki-roots`: hyper,
//! rustls and tokio-rustls are the coordinator's own server stack already,
//! so a webhook adds no client library of its own.

use http_body_util::Full;
use hyper::body::Bytes;
use hyper_util::rt::TokioIo;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};

/// How long one delivery attempt may take, connecting included.
pub const ATTEMPT_TIMEOUT: Duration = Duration::from_secs(10);

/// What became of one attempt.
#[derive(Debug, PartialEq, Eq)]
pub enum Answer {
    /// The receiver took the event (a 2xx status).
    Taken,
    /// The receiver refused it for good (a 4xx status other than 408 and
    /// 429): retrying the same body cannot help.
    Refused(u16),
    /// Try again later: no connection, a timeout, a 5xx, 408 or 429.
    Retry(String),
}

/// Posts event bodies.
#[derive(Clone)]
pub struct Poster {
    tls: tokio_rustls::TlsConnector,
}

impl Poster {
    /// A poster trusting the Mozilla roots for `https://` receivers.
    pub fn new() -> Result<Self, rustls::Error> {
        let roots = rustls::RootCertStore {
            roots: webpki_roots::TLS_SERVER_ROOTS.to_vec(),
        };
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let config = rustls::ClientConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()?
            .with_root_certificates(roots)
            .with_no_client_auth();
        Ok(Poster {
            tls: tokio_rustls::TlsConnector::from(Arc::new(config)),
        })
    }

    /// POSTs `body` (JSON) to `url` with `headers`, within
    /// [`ATTEMPT_TIMEOUT`].
    pub async fn post(&self, url: &http::Uri, headers: &[(&str, String)], body: Bytes) -> Answer {
        match tokio::time::timeout(ATTEMPT_TIMEOUT, self.attempt(url, headers, body)).await {
            Ok(Ok(status)) if (200..300).contains(&status) => Answer::Taken,
            Ok(Ok(status)) if (400..500).contains(&status) && status != 408 && status != 429 => {
                Answer::Refused(status)
            }
            Ok(Ok(status)) => Answer::Retry(format!("the receiver answered {status}")),
            Ok(Err(e)) => Answer::Retry(e),
            Err(_) => Answer::Retry(format!("no answer within {ATTEMPT_TIMEOUT:?}")),
        }
    }

    async fn attempt(
        &self,
        url: &http::Uri,
        headers: &[(&str, String)],
        body: Bytes,
    ) -> Result<u16, String> {
        let https = url.scheme_str() == Some("https");
        let host = url.host().ok_or("no host")?;
        let host = host.trim_start_matches('[').trim_end_matches(']');
        let port = url.port_u16().unwrap_or(if https { 443 } else { 80 });
        let mut req = http::Request::post(url.path_and_query().map_or("/", |p| p.as_str()))
            .header(
                http::header::HOST,
                url.authority().map_or("", |a| a.as_str()),
            )
            .header(http::header::CONTENT_TYPE, "application/json")
            .header(http::header::USER_AGENT, "trevi-coordinator")
            .header(http::header::CONNECTION, "close");
        for (name, value) in headers {
            req = req.header(*name, value);
        }
        let req = req.body(Full::new(body)).map_err(|e| e.to_string())?;
        let tcp = tokio::net::TcpStream::connect((host, port))
            .await
            .map_err(|e| format!("cannot connect: {e}"))?;
        if !https {
            return send(tcp, req).await;
        }
        let name = rustls::pki_types::ServerName::try_from(host.to_string())
            .map_err(|e| format!("bad server name {host}: {e}"))?;
        let tls = self
            .tls
            .connect(name, tcp)
            .await
            .map_err(|e| format!("TLS: {e}"))?;
        send(tls, req).await
    }
}

/// Sends `req` on a fresh connection `io`; its status.
async fn send<I>(io: I, req: http::Request<Full<Bytes>>) -> Result<u16, String>
where
    I: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let (mut sender, conn) = hyper::client::conn::http1::handshake(TokioIo::new(io))
        .await
        .map_err(|e| e.to_string())?;
    let conn = tokio::spawn(conn);
    let res = sender.send_request(req).await.map_err(|e| e.to_string());
    conn.abort();
    Ok(res?.status().as_u16())
}
