//! Accepting connections when file descriptors run short.
//!
//! - [`raise_fd_limit`]: at start-up the coordinator lifts its soft limit on
//!   open files to the hard limit, so the limit that bites is the one the
//!   operator set, not a shell's small default.
//! - [`accept`]: an accept that rides out errors. Out of descriptors
//!   (`EMFILE`), `accept` fails at once for as long as the shortage lasts;
//!   looping on it would spin a core, and giving up would stop the server
//!   for good. It waits [`ACCEPT_RETRY`] between tries and warns at most
//!   every [`ACCEPT_WARN_EVERY`].

use std::net::SocketAddr;
use std::time::{Duration, Instant};
use tokio::net::{TcpListener, TcpStream};

/// Pause after a failed `accept` before trying again.
pub const ACCEPT_RETRY: Duration = Duration::from_millis(50);

/// Least time between two warnings about failing `accept`s.
pub const ACCEPT_WARN_EVERY: Duration = Duration::from_secs(5);

/// The next connection on `listener` (`what` names it in warnings).
pub async fn accept(listener: &TcpListener, what: &str) -> (TcpStream, SocketAddr) {
    let mut warned: Option<Instant> = None;
    loop {
        match listener.accept().await {
            Ok(c) => return c,
            Err(e) => {
                if warned.is_none_or(|t| t.elapsed() >= ACCEPT_WARN_EVERY) {
                    tracing::warn!(error = %e, "{what}: cannot accept connections; retrying");
                    warned = Some(Instant::now());
                }
                tokio::time::sleep(ACCEPT_RETRY).await;
            }
        }
    }
}

/// Raises the soft limit on open files to the hard limit; returns the limit
/// now in force.
#[cfg(unix)]
pub fn raise_fd_limit() -> std::io::Result<u64> {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit only writes the struct it is given.
    if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut r) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    if r.rlim_cur < r.rlim_max {
        let raised = libc::rlimit {
            rlim_cur: r.rlim_max,
            rlim_max: r.rlim_max,
        };
        // SAFETY: setrlimit only reads the struct it is given.
        if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &raised) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
        r = raised;
    }
    #[allow(clippy::unnecessary_cast)] // rlim_t is not u64 on every unix.
    Ok(r.rlim_cur as u64)
}

/// Elsewhere the limit stays as it is.
#[cfg(not(unix))]
pub fn raise_fd_limit() -> std::io::Result<u64> {
    Ok(0)
}
