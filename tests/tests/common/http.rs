//! Plain HTTP/1.1 by hand to the coordinator's monitor: the tests look at
//! status codes and headers a full client would hide or fix up.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Duration;

/// Sends `request` (a whole raw HTTP/1.1 request) to `addr` and reads the
/// answer to the end: (status code, body). What arrived counts even when
/// the server resets the connection afterwards; the code is 0 when no
/// status line arrived.
pub fn request(addr: &str, request: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    s.write_all(request.as_bytes()).unwrap();
    let mut raw = String::new();
    let _ = s.read_to_string(&mut raw);
    parse_response(&raw)
}

/// `GET path`, with `Authorization: Bearer TOKEN` when given.
pub fn get(addr: &str, path: &str, token: Option<&str>) -> (u16, String) {
    let auth = token
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    request(
        addr,
        &format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\n{auth}Connection: close\r\n\r\n"),
    )
}

/// `POST path` with these extra header lines and `body`.
pub fn post(addr: &str, path: &str, headers: &[&str], body: &str) -> (u16, String) {
    let mut req = format!(
        "POST {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: {}\r\n",
        body.len()
    );
    for h in headers {
        req.push_str(h);
        req.push_str("\r\n");
    }
    req.push_str("\r\n");
    req.push_str(body);
    request(addr, &req)
}

/// (status code, body) of a raw HTTP/1.1 response; code 0 if there is none.
pub fn parse_response(raw: &str) -> (u16, String) {
    let (head, body) = raw.split_once("\r\n\r\n").unwrap_or((raw, ""));
    let code = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    (code, body.to_string())
}

/// Worker `name` as the monitor's `/api/state` shows it (its JSON object).
pub fn monitor_worker(c: &super::Coordinator, name: &str) -> serde_json::Value {
    let (code, text) = get(c.http.as_deref().unwrap(), "/api/state", None);
    assert_eq!(code, 200, "{text}");
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["workers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| w["name"] == name)
        .unwrap_or_else(|| panic!("no worker {name}: {text}"))
        .clone()
}
