//! Where events go: the URLs of `trevi-submit --notify` and of the
//! coordinator's `--events-url`, checked before anything is queued.

use crate::error::FarmError;

/// Most `--notify` URLs on one submission (and most `--events-url`s).
pub const MAX_NOTIFY_URLS: usize = 4;
/// Longest URL accepted, in bytes.
pub const MAX_URL_BYTES: usize = 2048;

/// Checks a submission's (or the coordinator's) event URLs: at most
/// [`MAX_NOTIFY_URLS`], each at most [`MAX_URL_BYTES`], `http://` or
/// `https://` with a host. Returns them without duplicates, in order.
pub fn check_urls(urls: &[String], what: &str) -> Result<Vec<String>, FarmError> {
    if urls.len() > MAX_NOTIFY_URLS {
        return Err(FarmError::Invalid(format!(
            "{what}: {} URLs, more than the {MAX_NOTIFY_URLS} allowed",
            urls.len()
        )));
    }
    let mut out: Vec<String> = Vec::with_capacity(urls.len());
    for url in urls {
        check_url(url).map_err(|why| FarmError::Invalid(format!("{what} {url:.80}: {why}")))?;
        if !out.contains(url) {
            out.push(url.clone());
        }
    }
    Ok(out)
}

/// Why `url` cannot receive events, if it cannot.
fn check_url(url: &str) -> Result<(), String> {
    if url.len() > MAX_URL_BYTES {
        return Err(format!(
            "{} bytes long, more than the {MAX_URL_BYTES} allowed",
            url.len()
        ));
    }
    // Lower case, as written: the scheme decides whether TLS is used.
    match url.split_once("://").map(|(scheme, _)| scheme) {
        Some("http" | "https") => {}
        Some(other) => {
            return Err(format!(
                "the scheme {other}:// is not allowed: only http:// and https://"
            ))
        }
        None => return Err("no scheme: expected http:// or https://".into()),
    }
    let uri: http::Uri = url
        .parse()
        .map_err(|e| format!("not a URL ({e}); expected http://host[:port]/path"))?;
    match uri.authority() {
        Some(a) if a.as_str().contains('@') => {
            Err("user information (user@host) is not allowed in the URL".into())
        }
        Some(a) if !a.host().is_empty() => Ok(()),
        _ => Err("no host".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn urls(u: &[&str]) -> Vec<String> {
        u.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn http_and_https_urls_are_kept_once_in_order() {
        let got = check_urls(
            &urls(&[
                "http://127.0.0.1:9000/hook",
                "https://hooks.example.com/trevi?x=1",
                "http://127.0.0.1:9000/hook",
            ]),
            "--notify",
        )
        .unwrap();
        assert_eq!(
            got,
            urls(&[
                "http://127.0.0.1:9000/hook",
                "https://hooks.example.com/trevi?x=1"
            ])
        );
    }

    #[test]
    fn hostile_urls_are_refused_saying_why() {
        for (url, says) in [
            ("file:///etc/passwd", "only http:// and https://"),
            ("ftp://example.com/x", "only http:// and https://"),
            ("gopher://example.com/", "only http:// and https://"),
            ("example.com/hook", "no scheme"),
            ("http:///nohost", "not a URL"),
            ("HTTP://example.com/", "only http:// and https://"),
            ("http://user:pw@example.com/", "user information"),
            ("http://exa mple.com/", "not a URL"),
        ] {
            let e = check_urls(&urls(&[url]), "--notify")
                .unwrap_err()
                .to_string();
            assert!(e.contains("--notify") && e.contains(says), "{url}: {e}");
        }
        let long = format!("http://example.com/{}", "a".repeat(MAX_URL_BYTES));
        let e = check_urls(&[long], "--notify").unwrap_err().to_string();
        assert!(e.contains("more than the 2048 allowed"), "{e}");
        let many = vec!["http://example.com/".to_string(); MAX_NOTIFY_URLS + 1];
        let e = check_urls(&many, "--notify").unwrap_err().to_string();
        assert!(e.contains("5 URLs"), "{e}");
        let most = vec!["http://example.com/".to_string(); MAX_NOTIFY_URLS];
        assert_eq!(check_urls(&most, "--notify").unwrap().len(), 1);
    }
}
