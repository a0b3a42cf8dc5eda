//! Who may call what: a secret token for submitters and another for
//! workers, presented as gRPC metadata `authorization: Bearer TOKEN`.
//!
//! - `trevi.v1.Jobs` needs the submit token; `trevi.v1.Workers` the worker
//!   token; `trevi.v1.Bundles` either (uploading needs the submit token,
//!   workers only download).
//! - A role without a configured token is open: with neither token the farm
//!   is open to anyone who can reach it, so a farm on a trusted network
//!   needs no setup.
//! - No token, or one matching neither role, is `UNAUTHENTICATED`; the other
//!   role's token is `PERMISSION_DENIED`.
//! - Health and reflection are always open (probes and `grpcurl list`).
//!
//! - Named submit tokens (`auth/named.rs`, `--submit-tokens-file`) also grant the
//!   submitter role, and name who submitted: the job records the name.
//!
//! Tokens are compared through their SHA-256 digests with a comparison that
//! looks at every byte, so the time taken does not tell how much of a guess
//! was right.

mod named;

pub use named::{
    parse_named_tokens, read_named_tokens, NamedToken, MAX_NAMED_TOKENS, MAX_TOKENS_FILE_BYTES,
    MAX_TOKEN_NAME_CHARS,
};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tonic::{Request, Status};

/// Why a token cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    /// A token that is empty or only whitespace.
    #[error("the {role} token is empty")]
    Empty {
        /// `"submit"` or `"worker"`.
        role: &'static str,
    },
    /// A token with a space, a control or a non-ASCII character: it could
    /// not travel in an `authorization` header.
    #[error("the {role} token must be printable ASCII without spaces")]
    NotPrintable {
        /// `"submit"` or `"worker"`.
        role: &'static str,
    },
    /// A token given both as a value and as a file.
    #[error("give the token or {}, not both", .file.display())]
    Both {
        /// The token file given.
        file: PathBuf,
    },
    /// The token file could not be read.
    #[error("cannot read {}: {source}", .file.display())]
    Read {
        /// The token file given.
        file: PathBuf,
        /// Why reading it failed.
        source: std::io::Error,
    },
    /// A line of the named tokens file is wrong (see `auth/named.rs`).
    #[error("{at}: {what}")]
    Named {
        /// `FILE:LINE` (line 0: the file as a whole).
        at: String,
        /// What is wrong.
        what: String,
    },
    /// A named token is also the plain submit token or the worker token.
    #[error("the named token {name} is also the {role} token: tokens must differ")]
    Shared {
        /// The named token's name.
        name: String,
        /// `"submit"` or `"worker"`.
        role: &'static str,
    },
}

/// The configured tokens (digests only).
#[derive(Clone, Default)]
pub struct Tokens {
    submit: Option<[u8; 32]>,
    /// Named submit tokens (see `auth/named.rs`).
    named: Vec<(Arc<str>, [u8; 32])>,
    worker: Option<[u8; 32]>,
}

fn digest(token: &str) -> [u8; 32] {
    Sha256::digest(token.as_bytes()).into()
}

/// Equality that reads both arrays whole, whatever their contents.
fn same(a: &[u8; 32], b: &[u8; 32]) -> bool {
    let diff = a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y));
    std::hint::black_box(diff) == 0
}

impl Tokens {
    /// `None` leaves that role open. Empty tokens are refused.
    pub fn new(submit: Option<&str>, worker: Option<&str>) -> Result<Tokens, TokenError> {
        for (role, t) in [("submit", submit), ("worker", worker)] {
            if let Some(t) = t {
                if t.trim().is_empty() {
                    return Err(TokenError::Empty { role });
                }
                if t.chars().any(|c| !c.is_ascii_graphic()) {
                    return Err(TokenError::NotPrintable { role });
                }
            }
        }
        Ok(Tokens {
            submit: submit.map(digest),
            named: Vec::new(),
            worker: worker.map(digest),
        })
    }

    /// Adds named submit tokens (checked by [`parse_named_tokens`]); each
    /// must differ from the plain submit token and the worker token.
    pub fn with_named(mut self, named: &[NamedToken]) -> Result<Tokens, TokenError> {
        for t in named {
            let d = digest(&t.token);
            for (role, other) in [("submit", &self.submit), ("worker", &self.worker)] {
                if other.is_some_and(|o| same(&o, &d)) {
                    return Err(TokenError::Shared {
                        name: t.name.clone(),
                        role,
                    });
                }
            }
            self.named.push((t.name.as_str().into(), d));
        }
        Ok(self)
    }

    /// Whether submitting needs no token.
    fn submit_open(&self) -> bool {
        self.submit.is_none() && self.named.is_empty()
    }

    /// Whether neither role has a token: anyone who can reach the farm may
    /// call anything.
    pub fn is_open(&self) -> bool {
        self.submit_open() && self.worker.is_none()
    }

    /// What the presented token (if any) lets its bearer do.
    pub fn grant(&self, presented: Option<&str>) -> Granted {
        let d = presented.map(digest);
        let ok = |want: &Option<[u8; 32]>| match (want, &d) {
            (None, _) => true,
            (Some(w), Some(d)) => same(w, d),
            (Some(_), None) => false,
        };
        // Every named token is compared, whichever matches.
        let mut name = None;
        if let Some(d) = &d {
            for (n, t) in &self.named {
                if same(t, d) {
                    name = Some(n.clone());
                }
            }
        }
        let submitter =
            self.submit_open() || name.is_some() || (self.submit.is_some() && ok(&self.submit));
        Granted {
            submitter,
            worker: ok(&self.worker),
            presented: presented.is_some(),
            name,
        }
    }
}

/// The roles a request's token grants; put in the request's extensions.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Granted {
    /// The request may submit and manage jobs and upload bundles.
    pub submitter: bool,
    /// The request may act as a worker.
    pub worker: bool,
    presented: bool,
    /// The named submit token presented (see `auth/named.rs`).
    pub name: Option<Arc<str>>,
}

impl Granted {
    /// Everything (no tokens configured, or in-process callers).
    pub const ALL: Granted = Granted {
        submitter: true,
        worker: true,
        presented: false,
        name: None,
    };

    fn refuse(&self, what: &str, needs: &str) -> Status {
        if !self.presented {
            Status::unauthenticated(format!(
                "{what} needs the {needs} token (authorization: Bearer TOKEN; --token or \
                 TREVI_TOKEN)"
            ))
        } else if self.submitter || self.worker {
            Status::permission_denied(format!("{what} needs the {needs} token"))
        } else {
            Status::unauthenticated(format!("{what}: the token is not valid"))
        }
    }

    /// Checks the submitter role.
    pub fn need_submitter(&self, what: &str) -> Result<(), Status> {
        if self.submitter {
            Ok(())
        } else {
            Err(self.refuse(what, "submit"))
        }
    }
}

/// The roles granted to `req` (everything when no interceptor ran).
pub fn granted<T>(req: &Request<T>) -> Granted {
    req.extensions()
        .get::<Granted>()
        .cloned()
        .unwrap_or(Granted::ALL)
}

/// Which roles a service admits.
#[derive(Debug, Clone, Copy)]
pub enum Need {
    /// The submit token (`trevi.v1.Jobs`).
    Submitter,
    /// The worker token (`trevi.v1.Workers`).
    Worker,
    /// Either token (`trevi.v1.Bundles`, which checks uploads itself).
    Either,
}

/// A tonic interceptor checking the token for one service.
#[derive(Clone)]
pub struct Auth {
    /// The farm's tokens.
    pub tokens: Arc<Tokens>,
    /// The roles the service admits.
    pub need: Need,
    /// The service's name, for the refusal's message.
    pub service: &'static str,
}

impl tonic::service::Interceptor for Auth {
    fn call(&mut self, mut req: Request<()>) -> Result<Request<()>, Status> {
        let presented = match req.metadata().get("authorization") {
            None => None,
            Some(v) => {
                let v = v
                    .to_str()
                    .map_err(|_| Status::unauthenticated("the authorization header is not text"))?;
                Some(v.strip_prefix("Bearer ").map(str::trim).ok_or_else(|| {
                    Status::unauthenticated("authorization must be \"Bearer TOKEN\"")
                })?)
            }
        };
        let g = self.tokens.grant(presented);
        let ok = match self.need {
            Need::Submitter => g.submitter,
            Need::Worker => g.worker,
            Need::Either => g.submitter || g.worker,
        };
        if !ok {
            let needs = match self.need {
                Need::Submitter => "submit",
                Need::Worker => "worker",
                Need::Either => "submit or worker",
            };
            return Err(g.refuse(self.service, needs));
        }
        req.extensions_mut().insert(g);
        Ok(req)
    }
}

/// Reads a token from a flag's value or a file (trailing newline dropped).
pub fn token_from(
    value: Option<String>,
    file: Option<&Path>,
) -> Result<Option<String>, TokenError> {
    match (value, file) {
        (Some(_), Some(f)) => Err(TokenError::Both { file: f.into() }),
        (Some(v), None) => Ok(Some(v)),
        (None, Some(f)) => std::fs::read_to_string(f)
            .map(|s| Some(s.trim_end_matches(['\n', '\r']).to_string()))
            .map_err(|source| TokenError::Read {
                file: f.into(),
                source,
            }),
        (None, None) => Ok(None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tonic::service::Interceptor;
    use tonic::Code;

    fn call(tokens: &Tokens, need: Need, header: Option<&str>) -> Result<Granted, Code> {
        let mut a = Auth {
            tokens: Arc::new(tokens.clone()),
            need,
            service: "svc",
        };
        let mut req = Request::new(());
        if let Some(h) = header {
            req.metadata_mut()
                .insert("authorization", h.parse().unwrap());
        }
        a.call(req)
            .map(|r| r.extensions().get::<Granted>().unwrap().clone())
            .map_err(|s| s.code())
    }

    #[test]
    fn roles_and_codes() {
        let t = Tokens::new(Some("sub-secret"), Some("work-secret")).unwrap();
        assert!(call(&t, Need::Submitter, Some("Bearer sub-secret")).is_ok());
        assert!(call(&t, Need::Worker, Some("Bearer work-secret")).is_ok());
        assert_eq!(
            call(&t, Need::Submitter, Some("Bearer work-secret")),
            Err(Code::PermissionDenied)
        );
        assert_eq!(
            call(&t, Need::Worker, Some("Bearer sub-secret")),
            Err(Code::PermissionDenied)
        );
        assert_eq!(call(&t, Need::Worker, None), Err(Code::Unauthenticated));
        assert_eq!(
            call(&t, Need::Either, Some("Bearer nope")),
            Err(Code::Unauthenticated)
        );
        assert_eq!(
            call(&t, Need::Either, Some("sub-secret")),
            Err(Code::Unauthenticated)
        );
        let g = call(&t, Need::Either, Some("Bearer work-secret")).unwrap();
        assert!(g.worker && !g.submitter);
        assert_eq!(
            g.need_submitter("upload").unwrap_err().code(),
            Code::PermissionDenied
        );
        // No tokens: open.
        let open = Tokens::default();
        assert!(open.is_open());
        assert!(call(&open, Need::Submitter, None).is_ok());
        // Only a worker token: submitting stays open.
        let w = Tokens::new(None, Some("w")).unwrap();
        assert!(call(&w, Need::Submitter, None).is_ok());
        assert_eq!(call(&w, Need::Worker, None), Err(Code::Unauthenticated));
        assert!(Tokens::new(Some(" "), None).is_err());
    }

    #[test]
    fn a_named_token_grants_the_submitter_role_and_names_its_bearer() {
        let named = parse_named_tokens("alice tok-a\nbob tok-b").unwrap();
        let t = Tokens::new(Some("plain"), Some("work"))
            .unwrap()
            .with_named(&named)
            .unwrap();
        let g = call(&t, Need::Submitter, Some("Bearer tok-b")).unwrap();
        assert_eq!(g.name.as_deref(), Some("bob"));
        let g = call(&t, Need::Submitter, Some("Bearer plain")).unwrap();
        assert_eq!(g.name, None);
        assert_eq!(
            call(&t, Need::Submitter, Some("Bearer tok-c")),
            Err(Code::Unauthenticated)
        );
        assert_eq!(
            call(&t, Need::Worker, Some("Bearer tok-a")),
            Err(Code::PermissionDenied)
        );
        // Named tokens alone close submitting to everyone else.
        let only = Tokens::default().with_named(&named).unwrap();
        assert!(!only.is_open());
        assert_eq!(
            call(&only, Need::Submitter, None),
            Err(Code::Unauthenticated)
        );
        assert!(call(&only, Need::Worker, None).is_ok());
        // A named token may not be another role's.
        let shared = parse_named_tokens("carol work").unwrap();
        let e = Tokens::new(None, Some("work"))
            .unwrap()
            .with_named(&shared)
            .err()
            .unwrap();
        assert!(e.to_string().contains("carol"), "{e}");
    }
}
