//! The signals that stop a Trevi process: SIGTERM (what `kill`, systemd,
//! Docker and Kubernetes send) and SIGINT (Ctrl-C); where there are no Unix
//! signals, Ctrl-C.
//!
//! [`shutdown`] waits for the first of them: `trevi-coordinator` and
//! `trevi-worker` stop gracefully on it (the worker hands its leases back,
//! the coordinator drains its connections). [`Signals`] catches both from
//! the moment it is made and says which arrived, for a program that must
//! exit with the signal's status.

/// A stop signal that arrived.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Signal {
    /// `SIGINT`, `SIGTERM` (or `Ctrl-C` without Unix signals).
    pub name: &'static str,
    /// The exit status that tells a shell which signal it was: 128 + the
    /// signal's number.
    pub code: i32,
}

/// SIGINT and SIGTERM, caught from now on instead of ending the process
/// where it stands.
pub struct Signals {
    #[cfg(unix)]
    int: tokio::signal::unix::Signal,
    #[cfg(unix)]
    term: tokio::signal::unix::Signal,
}

impl Signals {
    /// Starts catching both. Must run inside a Tokio runtime.
    pub fn catch() -> std::io::Result<Signals> {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{signal, SignalKind};
            Ok(Signals {
                int: signal(SignalKind::interrupt())?,
                term: signal(SignalKind::terminate())?,
            })
        }
        #[cfg(not(unix))]
        Ok(Signals {})
    }

    /// The next SIGINT or SIGTERM (including one that arrived since
    /// [`Signals::catch`]).
    pub async fn next(&mut self) -> Signal {
        #[cfg(unix)]
        {
            tokio::select! {
                _ = self.int.recv() => Signal { name: "SIGINT", code: 130 },
                _ = self.term.recv() => Signal { name: "SIGTERM", code: 143 },
            }
        }
        #[cfg(not(unix))]
        {
            let _ = tokio::signal::ctrl_c().await;
            Signal {
                name: "Ctrl-C",
                code: 130,
            }
        }
    }
}

/// Returns at the first SIGTERM or SIGINT (Ctrl-C) from now on.
///
/// # Panics
///
/// When the signals cannot be caught: outside a Tokio runtime, or one built
/// without its I/O driver.
pub async fn shutdown() {
    let mut signals = Signals::catch().expect("cannot catch SIGTERM and SIGINT");
    signals.next().await;
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    /// A SIGTERM sent to the process is caught, not fatal, and named.
    #[tokio::test]
    async fn sigterm_is_caught_and_named() {
        let mut signals = Signals::catch().unwrap();
        let kill = std::process::Command::new("kill")
            .args(["-TERM", &std::process::id().to_string()])
            .status()
            .unwrap();
        assert!(kill.success());
        let got = tokio::time::timeout(std::time::Duration::from_secs(60), signals.next())
            .await
            .expect("the signal arrives");
        assert_eq!(
            got,
            Signal {
                name: "SIGTERM",
                code: 143
            }
        );
    }
}
