//! Durations as users type them on every command line of the farm
//! (`--keep-ended-for 7d`, `--time-limit 90s`): a whole number and one of
//! `s`, `m`, `h`, `d`. One grammar for the coordinator and the client.

use std::time::Duration;

/// Text that is not a duration.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("\"{0}\" is not a duration like 90s, 30m, 12h or 7d")]
pub struct BadDuration(pub String);

/// Reads a whole number with `s`, `m`, `h` or `d` (`90s`, `10m`, `7d`).
pub fn parse(s: &str) -> Result<Duration, BadDuration> {
    let s = s.trim();
    let bad = || BadDuration(s.to_string());
    let unit = match s.chars().last().ok_or_else(bad)? {
        's' => 1,
        'm' => 60,
        'h' => 3600,
        'd' => 86400,
        _ => return Err(bad()),
    };
    let n: u64 = s[..s.len() - 1].parse().map_err(|_| bad())?;
    Ok(Duration::from_secs(n.checked_mul(unit).ok_or_else(bad)?))
}

/// The inverse of [`parse`], in the largest unit that divides it (whole
/// seconds).
pub fn format(d: Duration) -> String {
    let s = d.as_secs();
    for (unit, n) in [("d", 86400), ("h", 3600), ("m", 60)] {
        if s > 0 && s % n == 0 {
            return format!("{}{unit}", s / n);
        }
    }
    format!("{s}s")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_and_refusals() {
        assert_eq!(parse("90s"), Ok(Duration::from_secs(90)));
        assert_eq!(parse(" 10m "), Ok(Duration::from_secs(600)));
        assert_eq!(parse("2h"), Ok(Duration::from_secs(7200)));
        assert_eq!(parse("7d"), Ok(Duration::from_secs(7 * 86400)));
        for bad in [
            "",
            "s",
            "10",
            "1.5m",
            "-3s",
            "10w",
            "99999999999999999999d",
            "18446744073709551615d",
        ] {
            assert!(parse(bad).is_err(), "{bad}");
        }
        for d in [0, 59, 60, 90, 3600, 86400, 86401] {
            let d = Duration::from_secs(d);
            assert_eq!(parse(&format(d)), Ok(d));
        }
    }
}
