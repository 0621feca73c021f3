//! Integer-nanosecond time.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::ops::{Add, AddAssign, Sub, SubAssign};

/// A point in time or a duration, in integer nanoseconds.
///
/// Stamps are nanoseconds since the Unix epoch (UTC), like ROS 2 and MCAP log times.
/// Durations use the same type. Float seconds appear only at file boundaries (TUM).
#[derive(
    Copy, Clone, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
#[serde(transparent)]
pub struct Nanos(pub i64);

impl Nanos {
    /// Zero.
    pub const ZERO: Nanos = Nanos(0);
    /// One second.
    pub const SECOND: Nanos = Nanos(1_000_000_000);
    /// One millisecond.
    pub const MILLISECOND: Nanos = Nanos(1_000_000);

    /// From float seconds, rounded to the nearest nanosecond.
    pub fn from_secs_f64(s: f64) -> Nanos {
        Nanos((s * 1e9).round() as i64)
    }
    /// From whole seconds.
    pub const fn from_secs(s: i64) -> Nanos {
        Nanos(s * 1_000_000_000)
    }
    /// From whole milliseconds.
    pub const fn from_millis(ms: i64) -> Nanos {
        Nanos(ms * 1_000_000)
    }
    /// The period of a rate in hertz, rounded to the nearest nanosecond.
    pub fn period_of_hz(hz: f64) -> Nanos {
        Nanos((1e9 / hz).round() as i64)
    }
    /// As float seconds (for arithmetic in SI units; not for storage).
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 * 1e-9
    }
    /// The raw nanosecond count.
    pub const fn as_nanos(self) -> i64 {
        self.0
    }
    /// Formats as seconds with all nine nanosecond digits, as TUM files want
    /// (`1631696400.005000000`). Exact: no float rounding.
    pub fn to_secs_string(self) -> String {
        let sign = if self.0 < 0 { "-" } else { "" };
        let a = self.0.unsigned_abs();
        format!("{sign}{}.{:09}", a / 1_000_000_000, a % 1_000_000_000)
    }
    /// Parses decimal seconds (`"1631696400.005"`, `"-0.5"`, `"12"`) exactly into nanoseconds.
    /// Digits beyond the ninth decimal are rounded half away from zero.
    pub fn parse_secs(s: &str) -> Option<Nanos> {
        let s = s.trim();
        let (neg, body) = match s.strip_prefix('-') {
            Some(rest) => (true, rest),
            None => (false, s.strip_prefix('+').unwrap_or(s)),
        };
        let (int_part, frac_part) = match body.split_once('.') {
            Some((i, f)) => (i, f),
            None => (body, ""),
        };
        if int_part.is_empty() && frac_part.is_empty() {
            return None;
        }
        if !int_part.bytes().all(|b| b.is_ascii_digit())
            || !frac_part.bytes().all(|b| b.is_ascii_digit())
        {
            return None;
        }
        let whole: i64 = if int_part.is_empty() {
            0
        } else {
            int_part.parse().ok()?
        };
        let mut frac: i64 = 0;
        for (i, b) in frac_part.bytes().enumerate() {
            let d = i64::from(b - b'0');
            if i < 9 {
                frac = frac * 10 + d;
            } else {
                if i == 9 && d >= 5 {
                    frac += 1;
                }
                break;
            }
        }
        for _ in frac_part.len().min(9)..9 {
            frac *= 10;
        }
        let total = whole.checked_mul(1_000_000_000)?.checked_add(frac)?;
        Some(Nanos(if neg { -total } else { total }))
    }
}

impl Add for Nanos {
    type Output = Nanos;
    fn add(self, rhs: Nanos) -> Nanos {
        Nanos(self.0 + rhs.0)
    }
}
impl Sub for Nanos {
    type Output = Nanos;
    fn sub(self, rhs: Nanos) -> Nanos {
        Nanos(self.0 - rhs.0)
    }
}
impl AddAssign for Nanos {
    fn add_assign(&mut self, rhs: Nanos) {
        self.0 += rhs.0;
    }
}
impl SubAssign for Nanos {
    fn sub_assign(&mut self, rhs: Nanos) {
        self.0 -= rhs.0;
    }
}
impl fmt::Display for Nanos {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} s", self.to_secs_string())
    }
}

/// Parses `YYYY-MM-DDTHH:MM:SS[.fff]Z` (UTC, RFC 3339 subset) into nanoseconds since the epoch.
pub fn parse_utc(s: &str) -> Option<Nanos> {
    let s = s.trim();
    let s = s.strip_suffix('Z').or_else(|| s.strip_suffix("+00:00"))?;
    let (date, time) = s.split_once(['T', ' '])?;
    let mut d = date.split('-');
    let y: i64 = d.next()?.parse().ok()?;
    let m: i64 = d.next()?.parse().ok()?;
    let day: i64 = d.next()?.parse().ok()?;
    // RFC 3339 years have four digits; beyond them the nanoseconds would overflow anyway.
    if d.next().is_some()
        || !(0..=9999).contains(&y)
        || !(1..=12).contains(&m)
        || !(1..=31).contains(&day)
    {
        return None;
    }
    let mut t = time.split(':');
    let hh: i64 = t.next()?.parse().ok()?;
    let mm: i64 = t.next()?.parse().ok()?;
    let ss = Nanos::parse_secs(t.next()?)?;
    if t.next().is_some() || hh > 23 || mm > 59 || ss.0 < 0 || ss.0 >= 61_000_000_000 {
        return None;
    }
    // Days from civil (Howard Hinnant's algorithm).
    let y2 = if m <= 2 { y - 1 } else { y };
    let era = y2.div_euclid(400);
    let yoe = y2 - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe - 719_468;
    // Nanoseconds in an i64 end in 2262: later times are not representable.
    let secs = days * 86_400 + hh * 3600 + mm * 60;
    secs.checked_mul(1_000_000_000)
        .and_then(|n| n.checked_add(ss.0))
        .map(Nanos)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn utc_beyond_i64_nanoseconds_is_refused() {
        // i64 nanoseconds end at 2262-04-11T23:47:16.854775807Z.
        assert!(parse_utc("2262-04-11T23:47:16Z").is_some());
        assert_eq!(parse_utc("2262-04-11T23:47:17Z"), None);
        assert_eq!(parse_utc("9999-12-31T23:59:59Z"), None);
        assert_eq!(parse_utc("99999999999999-01-01T00:00:00Z"), None);
        assert!(parse_utc("1969-12-31T23:59:59Z").is_some_and(|t| t.0 < 0));
    }

    #[test]
    fn utc_known_epochs() {
        assert_eq!(parse_utc("1970-01-01T00:00:00Z"), Some(Nanos(0)));
        // `date -u -d 2021-09-15T09:00:00Z +%s` = 1631696400
        assert_eq!(
            parse_utc("2021-09-15T09:00:00Z"),
            Some(Nanos::from_secs(1_631_696_400))
        );
        assert_eq!(
            parse_utc("2000-02-29T12:00:00.5Z"),
            Some(Nanos::from_secs(951_825_600) + Nanos(500_000_000))
        );
        assert_eq!(parse_utc("2021-13-01T00:00:00Z"), None);
        assert_eq!(parse_utc("2021-09-15 09:00:00"), None);
    }

    #[test]
    fn secs_string_examples() {
        assert_eq!(Nanos(1_500_000_001).to_secs_string(), "1.500000001");
        assert_eq!(Nanos(-5).to_secs_string(), "-0.000000005");
        assert_eq!(Nanos::parse_secs("1.5"), Some(Nanos(1_500_000_000)));
        assert_eq!(Nanos::parse_secs(".25"), Some(Nanos(250_000_000)));
        assert_eq!(Nanos::parse_secs("0.0000000015"), Some(Nanos(2)));
        assert_eq!(Nanos::parse_secs("1e3"), None);
        assert_eq!(Nanos::parse_secs(""), None);
    }

    proptest! {
        #[test]
        fn secs_string_round_trips(n in -4_000_000_000_000_000_000i64..4_000_000_000_000_000_000i64) {
            prop_assert_eq!(Nanos::parse_secs(&Nanos(n).to_secs_string()), Some(Nanos(n)));
        }
    }
}
