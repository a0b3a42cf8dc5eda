//! Named submit tokens (`--submit-tokens-file`): one token per person or
//! pipeline, so the farm tells submitters apart by who they are rather
//! than by the address they call from. A job records its token's name as
//! its submitter: `status` shows it, the per-submitter job limit counts by
//! it, and the usage history groups by it (`trevi-submit usage --by
//! submitter`). A job submitted with the plain `--submit-token`, or to a
//! farm without tokens, is its client's address, as before.
//!
//! The file: one `NAME TOKEN` a line (blank lines and `#` comments
//! skipped). A name is 1 to [`MAX_TOKEN_NAME_CHARS`] of `A-Z a-z 0-9 . _ @
//! -`; a token printable ASCII without spaces. Names and tokens are each
//! unique. Bounds, checked before the file is read into memory: at most
//! [`MAX_TOKENS_FILE_BYTES`] bytes and [`MAX_NAMED_TOKENS`] tokens (each
//! request compares its token with every one: 1024 SHA-256 comparisons of
//! 32 bytes cost microseconds).

use super::TokenError;
use std::io::Read;
use std::path::Path;

/// Largest tokens file read.
pub const MAX_TOKENS_FILE_BYTES: u64 = 64 << 10;
/// Most named tokens in the file.
pub const MAX_NAMED_TOKENS: usize = 1024;
/// Longest token name.
pub const MAX_TOKEN_NAME_CHARS: usize = 64;

/// A submit token and the name jobs submitted with it are recorded under.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NamedToken {
    /// Who the token is for.
    pub name: String,
    /// The secret.
    pub token: String,
}

/// Reads `--submit-tokens-file` (see the module documentation).
pub fn read_named_tokens(path: &Path) -> Result<Vec<NamedToken>, TokenError> {
    let bad = |line: usize, what: String| TokenError::Named {
        at: format!("{}:{line}", path.display()),
        what,
    };
    let read = |source| TokenError::Read {
        file: path.into(),
        source,
    };
    let file = std::fs::File::open(path).map_err(read)?;
    let len = file.metadata().map_err(read)?.len();
    if len > MAX_TOKENS_FILE_BYTES {
        return Err(bad(
            0,
            format!("{len} bytes: a tokens file has at most {MAX_TOKENS_FILE_BYTES}"),
        ));
    }
    let mut text = String::new();
    file.take(MAX_TOKENS_FILE_BYTES)
        .read_to_string(&mut text)
        .map_err(read)?;
    parse_named_tokens(&text).map_err(|(line, what)| bad(line, what))
}

/// The tokens of a tokens file's text, or the (1-based) line and what is
/// wrong with it.
pub fn parse_named_tokens(text: &str) -> Result<Vec<NamedToken>, (usize, String)> {
    let mut out: Vec<NamedToken> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut words = line.split_ascii_whitespace();
        let (Some(name), Some(token), None) = (words.next(), words.next(), words.next()) else {
            return Err((n, "expected NAME TOKEN".into()));
        };
        let name_ok = name.chars().count() <= MAX_TOKEN_NAME_CHARS
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '@' | '-'));
        if !name_ok {
            return Err((
                n,
                format!(
                    "a name is 1 to {MAX_TOKEN_NAME_CHARS} of A-Z a-z 0-9 . _ @ - (the first \
                     word of the line)"
                ),
            ));
        }
        if !token.chars().all(|c| c.is_ascii_graphic()) {
            return Err((n, "a token is printable ASCII without spaces".into()));
        }
        if out.iter().any(|t| t.name == name) {
            return Err((n, format!("the name {name} is given twice")));
        }
        if out.iter().any(|t| t.token == token) {
            return Err((n, "this token is given twice".into()));
        }
        if out.len() == MAX_NAMED_TOKENS {
            return Err((n, format!("more than {MAX_NAMED_TOKENS} tokens")));
        }
        out.push(NamedToken {
            name: name.into(),
            token: token.into(),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tokens_file_is_read_or_refused_at_its_line() {
        let t = parse_named_tokens("# farm\n\nalice s3cret-a\n  bob.render  s3cret-b \n").unwrap();
        assert_eq!(
            t.iter()
                .map(|t| (t.name.as_str(), t.token.as_str()))
                .collect::<Vec<_>>(),
            [("alice", "s3cret-a"), ("bob.render", "s3cret-b")]
        );
        for (text, line, says) in [
            ("alice", 1, "NAME TOKEN"),
            ("a b c", 1, "NAME TOKEN"),
            ("ok t1\nal ice t2", 2, "NAME TOKEN"),
            ("al/ice t", 1, "a name is"),
            (&format!("{} t", "n".repeat(65)), 1, "a name is"),
            ("alice t1\nalice t2", 2, "twice"),
            ("alice t1\nbob t1", 2, "twice"),
            ("alice tok\u{e9}n", 1, "printable"),
        ] {
            let (n, what) = parse_named_tokens(text).unwrap_err();
            assert_eq!(n, line, "{text:?}");
            assert!(what.contains(says), "{text:?}: {what}");
        }
        let many: String = (0..=MAX_NAMED_TOKENS)
            .map(|i| format!("n{i} t{i}\n"))
            .collect();
        let (n, what) = parse_named_tokens(&many).unwrap_err();
        assert_eq!(n, MAX_NAMED_TOKENS + 1);
        assert!(what.contains("more than"), "{what}");
    }

    #[test]
    fn a_tokens_file_over_its_bound_is_refused_before_it_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tokens");
        let f = std::fs::File::create(&path).unwrap();
        // Sparse: 1 GiB claimed, nothing written.
        f.set_len(1 << 30).unwrap();
        let e = read_named_tokens(&path).unwrap_err().to_string();
        assert!(e.contains("tokens") && e.contains("at most 65536"), "{e}");
        std::fs::write(&path, "alice a-secret\n").unwrap();
        assert_eq!(read_named_tokens(&path).unwrap()[0].name, "alice");
    }
}
