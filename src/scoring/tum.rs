//! TUM trajectory files: `t tx ty tz qx qy qz qw`, one pose per line.
//!
//! Each line holds the pose `world_from_body` at time `t`: `t` in seconds (Unix epoch,
//! written with all nine nanosecond digits), the body origin in the ENU world frame
//! (`tx ty tz`, metres) and the body orientation in the world frame as a unit quaternion
//! (`qx qy qz qw`, scalar last).
//!
//! **Writing** ([`format_tum`], [`write_tum`]) is lossless: stamps come from
//! [`Nanos::to_secs_string`] (exact), every float is written in Rust's shortest
//! round-trip form, and the quaternion is written as the representative with `qw ≥ 0`
//! (the sign flip is an exact negation; `q` and `-q` are the same rotation). A file holds
//! one `#` header line, single spaces between columns and no trailing spaces, exactly what
//! evo's `file_interface.read_tum_trajectory_file` accepts. Covariances are not written
//! (TUM has no place for them).
//!
//! **Reading** ([`parse_tum`], [`read_tum`]) accepts `#` comment lines, blank lines and any
//! run of spaces or tabs between columns; stamps are parsed exactly as decimal seconds
//! (also with an exponent, as `numpy.savetxt` writes them: `1.631696400005e+09`).
//! Quaternions whose norm is within [`QUAT_NORM_TOLERANCE`] of 1 are accepted; those not
//! already unit to floating-point precision are normalised, the others are kept
//! bit-for-bit, so `read(write(traj))` returns every stamp, position and quaternion
//! component bit-exactly (quaternions with `qw < 0` come back negated).

use super::spool::Poses;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::fmt::Write as _;
use std::io;
use std::path::{Path, PathBuf};
use thiserror::Error;
use vinebench_msgs::{Nanos, PoseSample, Trajectory};

/// Largest accepted `|‖q‖ − 1|` of a quaternion read from a file (files written by other
/// tools with a few decimals are off by ~1e-4 at most).
pub const QUAT_NORM_TOLERANCE: f64 = 1e-3;

/// Below this `|‖q‖ − 1|` a quaternion read from a file is taken as it is (it is unit to
/// floating-point precision); above it, it is normalised.
const QUAT_KEEP_TOLERANCE: f64 = 1e-12;

/// Column names of a TUM line, in order.
pub const COLUMNS: [&str; 8] = ["t", "tx", "ty", "tz", "qx", "qy", "qz", "qw"];

/// The header line written at the top of every file.
const HEADER: &str = "# t tx ty tz qx qy qz qw (world_from_body: t s, position m in ENU world, \
                      unit quaternion scalar-last with qw >= 0)";

/// What is wrong with one line of a TUM file.
#[derive(Clone, Debug, PartialEq, Error)]
pub enum TumLineError {
    /// The line does not hold eight columns.
    #[error("expected 8 numbers `t tx ty tz qx qy qz qw`, found {found} column(s)")]
    ColumnCount {
        /// Number of whitespace-separated columns found.
        found: usize,
    },
    /// The stamp is not decimal seconds.
    #[error("column 1 (t): expected decimal seconds, found `{text}`")]
    BadStamp {
        /// The text of the column.
        text: String,
    },
    /// A pose column is not a number.
    #[error("column {column} ({name}): expected a number, found `{text}`")]
    NotANumber {
        /// 1-based column.
        column: usize,
        /// Column name (`tx`, `qw`, ...).
        name: &'static str,
        /// The text of the column.
        text: String,
    },
    /// A pose column is NaN or infinite.
    #[error("column {column} ({name}): expected a finite number, found `{text}`")]
    NotFinite {
        /// 1-based column.
        column: usize,
        /// Column name.
        name: &'static str,
        /// The text of the column.
        text: String,
    },
    /// The stamp is not after the previous pose's stamp.
    #[error(
        "column 1 (t): expected a time strictly after the previous pose's {previous}, found {found}"
    )]
    TimeNotIncreasing {
        /// Stamp of the previous pose.
        previous: Nanos,
        /// Stamp on this line.
        found: Nanos,
    },
    /// The quaternion is not of unit norm.
    #[error(
        "columns 5-8 (qx qy qz qw): expected a unit quaternion (|norm - 1| <= {QUAT_NORM_TOLERANCE}), found norm {norm}"
    )]
    NotUnitQuaternion {
        /// Norm of the quaternion on the line.
        norm: f64,
    },
}

/// A TUM file could not be read.
#[derive(Debug, Error)]
pub enum TumError {
    /// The file could not be read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the OS said.
        #[source]
        source: io::Error,
    },
    /// A line is malformed.
    #[error("{}:{line}: {error}", path.display())]
    Line {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with the line.
        error: TumLineError,
    },
}

/// Formats one float so that parsing it back (Rust or Python `float`) gives the same bits:
/// the shortest round-trip digits, positional for ordinary magnitudes, with an exponent
/// otherwise (so 1e-300 does not take 300 characters).
fn push_f64(out: &mut String, x: f64) {
    let a = x.abs();
    // `write!` into a String cannot fail.
    let _ = if a == 0.0 || (1e-5..1e16).contains(&a) || !a.is_finite() {
        write!(out, "{x}")
    } else {
        write!(out, "{x:e}")
    };
}

/// The quaternion components `[qx, qy, qz, qw]` as written: `q` itself when `qw ≥ 0`, else
/// `−q` computed as `0 − x` (exact, and zeros come out as `+0` rather than `-0`).
pub fn canonical_quaternion(q: &UnitQuaternion<f64>) -> Quaternion<f64> {
    let q = *q.quaternion();
    if q.w < 0.0 {
        Quaternion::new(0.0 - q.w, 0.0 - q.i, 0.0 - q.j, 0.0 - q.k)
    } else {
        q
    }
}

/// The text of a TUM file for `traj`: a `#` header line, then one line per pose
/// (`t tx ty tz qx qy qz qw`, see the [module docs](self)). Lossless for finite values;
/// non-finite values are written as `NaN`/`inf`, which [`read_tum`] rejects.
pub fn format_tum(traj: &Trajectory) -> String {
    let mut out = String::with_capacity(64 + traj.len() * 160);
    out.push_str(HEADER);
    out.push('\n');
    for s in &traj.samples {
        push_line(&mut out, s.stamp, &s.world_from_body);
    }
    out
}

/// One pose line of a TUM file.
fn push_line(out: &mut String, stamp: Nanos, pose: &Isometry3<f64>) {
    let p = pose.translation.vector;
    let q = canonical_quaternion(&pose.rotation);
    out.push_str(&stamp.to_secs_string());
    for x in [p.x, p.y, p.z, q.i, q.j, q.k, q.w] {
        out.push(' ');
        push_f64(out, x);
    }
    out.push('\n');
}

/// Writes `poses` as a TUM file (the text of [`format_tum`]), streamed: a long run's
/// trajectory on disk is never whole in memory. Refuses (`InvalidInput`) a pose with a
/// non-finite position or quaternion component, which could not be read back; the file
/// is then left as it was (written whole or not at all).
pub fn write_tum(path: impl AsRef<Path>, poses: &dyn Poses) -> io::Result<()> {
    let path = path.as_ref();
    crate::fsio::write_atomic_with(path, |w| {
        writeln!(w, "{HEADER}")?;
        let mut line = String::with_capacity(192);
        for (stamp, pose) in poses.poses() {
            let p = pose.translation.vector;
            let q = pose.rotation.coords;
            if !(p.iter().all(|x| x.is_finite()) && q.iter().all(|x| x.is_finite())) {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!(
                        "{}: pose at {stamp} has a non-finite component",
                        path.display()
                    ),
                ));
            }
            line.clear();
            push_line(&mut line, stamp, &pose);
            w.write_all(line.as_bytes())?;
        }
        // A pass that a read error ended early must not leave a short file as if whole.
        poses.check()
    })
}

/// Reads a TUM file (see the [module docs](self) for what is accepted).
pub fn read_tum(path: impl AsRef<Path>) -> Result<Trajectory, TumError> {
    let path = path.as_ref();
    let text =
        crate::fsio::read_text_bounded(path, crate::fsio::MAX_TUM_BYTES).map_err(|source| {
            TumError::Io {
                path: path.to_path_buf(),
                source,
            }
        })?;
    parse_tum(&text, path)
}

/// Parses the text of a TUM file; `path` only names the file in errors.
pub fn parse_tum(text: &str, path: &Path) -> Result<Trajectory, TumError> {
    let mut traj = Trajectory::new();
    for (i, line) in text.lines().enumerate() {
        let body = line.trim();
        if body.is_empty() || body.starts_with('#') {
            continue;
        }
        let sample = parse_line(body, traj.samples.last().map(|s| s.stamp)).map_err(|error| {
            TumError::Line {
                path: path.to_path_buf(),
                line: i + 1,
                error,
            }
        })?;
        traj.samples.push(sample);
    }
    Ok(traj)
}

/// Parses one non-comment line.
fn parse_line(body: &str, previous: Option<Nanos>) -> Result<PoseSample, TumLineError> {
    let cols: Vec<&str> = body.split_ascii_whitespace().collect();
    if cols.len() != 8 {
        return Err(TumLineError::ColumnCount { found: cols.len() });
    }
    let stamp = parse_stamp(cols[0]).ok_or_else(|| TumLineError::BadStamp {
        text: cols[0].to_string(),
    })?;
    if let Some(previous) = previous {
        if stamp <= previous {
            return Err(TumLineError::TimeNotIncreasing {
                previous,
                found: stamp,
            });
        }
    }
    let mut v = [0.0f64; 7];
    for (k, slot) in v.iter_mut().enumerate() {
        let column = k + 2;
        let text = cols[k + 1];
        let name = COLUMNS[k + 1];
        let x: f64 = text.parse().map_err(|_| TumLineError::NotANumber {
            column,
            name,
            text: text.to_string(),
        })?;
        if !x.is_finite() {
            return Err(TumLineError::NotFinite {
                column,
                name,
                text: text.to_string(),
            });
        }
        *slot = x;
    }
    let q = Quaternion::new(v[6], v[3], v[4], v[5]);
    let norm = q.norm();
    if (norm - 1.0).abs() > QUAT_NORM_TOLERANCE || norm.is_nan() {
        return Err(TumLineError::NotUnitQuaternion { norm });
    }
    let rotation = if (norm - 1.0).abs() <= QUAT_KEEP_TOLERANCE {
        UnitQuaternion::new_unchecked(q)
    } else {
        UnitQuaternion::from_quaternion(q)
    };
    Ok(PoseSample {
        stamp,
        world_from_body: Isometry3::from_parts(Translation3::new(v[0], v[1], v[2]), rotation),
        covariance: None,
    })
}

/// Largest decimal exponent shift accepted in a stamp (beyond it no stamp fits in `i64`
/// nanoseconds, or it rounds to zero).
const MAX_STAMP_EXPONENT: i64 = 40;

/// Parses decimal seconds exactly into nanoseconds, also with an exponent
/// (`1.631696400005e+09`), rounding beyond the ninth decimal half away from zero like
/// [`Nanos::parse_secs`].
pub fn parse_stamp(text: &str) -> Option<Nanos> {
    if let Some(n) = Nanos::parse_secs(text) {
        return Some(n);
    }
    let (mantissa, exponent) = text.trim().split_once(['e', 'E'])?;
    let exponent: i64 = exponent.parse().ok()?;
    let (sign, body) = match mantissa.strip_prefix('-') {
        Some(rest) => ("-", rest),
        None => ("", mantissa.strip_prefix('+').unwrap_or(mantissa)),
    };
    let (int_part, frac_part) = body.split_once('.').unwrap_or((body, ""));
    if (int_part.is_empty() && frac_part.is_empty())
        || !int_part
            .bytes()
            .chain(frac_part.bytes())
            .all(|b| b.is_ascii_digit())
    {
        return None;
    }
    if exponent.abs() > MAX_STAMP_EXPONENT {
        // Too large for i64 nanoseconds, or smaller than half a nanosecond.
        return (exponent < 0).then_some(Nanos::ZERO);
    }
    let digits: String = format!("{int_part}{frac_part}");
    // Position of the decimal point within `digits` after applying the exponent.
    let point = int_part.len() as i64 + exponent;
    let shifted = if point <= 0 {
        format!(
            "{sign}0.{}{digits}",
            "0".repeat(point.unsigned_abs() as usize)
        )
    } else if point as usize >= digits.len() {
        format!(
            "{sign}{digits}{}",
            "0".repeat(point as usize - digits.len())
        )
    } else {
        let (a, b) = digits.split_at(point as usize);
        format!("{sign}{a}.{b}")
    };
    Nanos::parse_secs(&shifted)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Quaternion;
    use proptest::prelude::*;

    fn sample(t: i64, p: [f64; 3], q: [f64; 4]) -> PoseSample {
        PoseSample {
            stamp: Nanos(t),
            world_from_body: Isometry3::from_parts(
                Translation3::new(p[0], p[1], p[2]),
                UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2])),
            ),
            covariance: None,
        }
    }

    /// Any finite float, including subnormals, zeros of both signs and huge values.
    fn finite_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            prop::num::f64::NORMAL | prop::num::f64::SUBNORMAL | prop::num::f64::ZERO,
            -1e4..1e4f64,
        ]
    }

    fn unit_quaternion() -> impl Strategy<Value = UnitQuaternion<f64>> {
        (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64)
            .prop_filter("not near zero", |(a, b, c, d)| {
                a * a + b * b + c * c + d * d > 1e-3
            })
            .prop_map(|(a, b, c, d)| UnitQuaternion::from_quaternion(Quaternion::new(a, b, c, d)))
    }

    fn trajectory() -> impl Strategy<Value = Trajectory> {
        (
            -2_000_000_000_000_000_000i64..2_000_000_000_000_000_000i64,
            prop::collection::vec(
                (
                    1i64..10_000_000_000,
                    finite_f64(),
                    finite_f64(),
                    finite_f64(),
                    unit_quaternion(),
                ),
                0..20,
            ),
        )
            .prop_map(|(t0, steps)| {
                let mut traj = Trajectory::new();
                let mut t = t0;
                for (dt, x, y, z, q) in steps {
                    t += dt;
                    traj.samples.push(PoseSample {
                        stamp: Nanos(t),
                        world_from_body: Isometry3::from_parts(Translation3::new(x, y, z), q),
                        covariance: None,
                    });
                }
                traj
            })
    }

    proptest! {
        #[test]
        fn write_then_read_is_bit_exact(traj in trajectory()) {
            let text = format_tum(&traj);
            let back = parse_tum(&text, Path::new("mem.tum")).unwrap();
            prop_assert_eq!(back.len(), traj.len());
            for (a, b) in traj.samples.iter().zip(&back.samples) {
                prop_assert_eq!(a.stamp, b.stamp);
                let pa = a.world_from_body.translation.vector;
                let pb = b.world_from_body.translation.vector;
                for k in 0..3 {
                    prop_assert_eq!(pa[k].to_bits(), pb[k].to_bits());
                }
                // The file holds the qw >= 0 representative: q, or an exact negation.
                let qa = a.world_from_body.rotation.coords;
                let qb = b.world_from_body.rotation.coords;
                let sign = if qa.w < 0.0 { -1.0 } else { 1.0 };
                for k in 0..4 {
                    let expected: f64 = sign * qa[k];
                    if expected == 0.0 {
                        prop_assert_eq!(qb[k], 0.0);
                    } else {
                        prop_assert_eq!(expected.to_bits(), qb[k].to_bits());
                    }
                }
                prop_assert!(qb.w >= 0.0);
            }
            // Writing what was read gives the same text again.
            prop_assert_eq!(format_tum(&back), text);
        }

        #[test]
        fn exponent_stamps_are_exact(n in -4_000_000_000_000_000_000i64..4_000_000_000_000_000_000i64) {
            // numpy.savetxt's '%.18e' has 19 significant digits: enough for every i64 ns.
            let secs = Nanos(n).to_secs_string();
            let neg = secs.starts_with('-');
            let digits: String = secs.trim_start_matches('-').replace('.', "");
            let trimmed = digits.trim_start_matches('0');
            prop_assume!(!trimmed.is_empty());
            // Scientific form d.ddd...e<exp> of the same decimal number.
            let exp = trimmed.len() as i64 - 10;
            let text = format!(
                "{}{}.{}e{:+03}",
                if neg { "-" } else { "" },
                &trimmed[..1],
                &trimmed[1..],
                exp
            );
            prop_assert_eq!(parse_stamp(&text), Some(Nanos(n)), "{}", text);
        }
    }

    #[test]
    fn format_is_what_evo_reads() {
        let mut traj = Trajectory::new();
        traj.push(sample(
            1_631_696_400_005_000_000,
            [1.5, -2.0, 0.25],
            [0.0, 0.0, 0.0, -1.0],
        ));
        let text = format_tum(&traj);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 2);
        assert!(lines[0].starts_with('#'));
        // Single spaces, no trailing space, qw flipped to +1, nine ns digits.
        assert_eq!(lines[1], "1631696400.005000000 1.5 -2 0.25 0 0 0 1");
    }

    #[test]
    fn reads_comments_blank_lines_and_numpy_output() {
        let text = "# header\n\n  \t\n1.631696400005000000e+09 1.0e+00 2 3 0 0 0 1\n\
                    # mid comment\n1631696400.0060000004   4 5 6 0 0 0.7071067811865476 0.7071067811865476\n";
        let t = parse_tum(text, Path::new("x.tum")).unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t.samples[0].stamp, Nanos(1_631_696_400_005_000_000));
        assert_eq!(t.samples[1].stamp, Nanos(1_631_696_400_006_000_000));
        assert_eq!(t.samples[0].world_from_body.translation.x, 1.0);
        let yaw = t.samples[1].world_from_body.rotation.euler_angles().2;
        assert!((yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn slightly_off_quaternions_are_normalised() {
        let text = "0 0 0 0 0 0 0.7071 0.7071\n";
        let t = parse_tum(text, Path::new("x.tum")).unwrap();
        let q = t.samples[0].world_from_body.rotation;
        assert!((q.norm() - 1.0).abs() < 1e-15);
    }

    fn line_error(text: &str) -> (usize, TumLineError, String) {
        match parse_tum(text, Path::new("dir/est.tum")) {
            Err(e @ TumError::Line { .. }) => {
                let msg = e.to_string();
                let TumError::Line { line, error, .. } = e else {
                    unreachable!()
                };
                (line, error, msg)
            }
            other => panic!("expected a line error, got {other:?}"),
        }
    }

    #[test]
    fn malformed_lines_name_file_line_and_column() {
        let good = "# c\n1.0 0 0 0 0 0 0 1\n";
        let (line, err, msg) = line_error(&format!("{good}2.0 0 0 0 0 0 1\n"));
        assert_eq!((line, err), (3, TumLineError::ColumnCount { found: 7 }));
        assert!(
            msg.starts_with("dir/est.tum:3: expected 8 numbers"),
            "{msg}"
        );

        let (line, err, msg) = line_error(&format!("{good}\n2.0 0 abc 0 0 0 0 1\n"));
        assert_eq!(line, 4);
        assert!(matches!(
            err,
            TumLineError::NotANumber {
                column: 3,
                name: "ty",
                ..
            }
        ));
        assert!(msg.contains("dir/est.tum:4: column 3 (ty)"), "{msg}");

        let (line, err, _) = line_error(&format!("{good}2.0 0 0 nan 0 0 0 1\n"));
        assert_eq!(line, 3);
        assert!(matches!(
            err,
            TumLineError::NotFinite {
                column: 4,
                name: "tz",
                ..
            }
        ));

        let (line, err, msg) = line_error(&format!("{good}1.0 0 0 0 0 0 0 1\n"));
        assert_eq!(line, 3);
        assert!(matches!(err, TumLineError::TimeNotIncreasing { .. }));
        assert!(msg.contains("strictly after"), "{msg}");

        let (_, err, _) = line_error(&format!("{good}2,5 0 0 0 0 0 0 1\n"));
        assert!(matches!(err, TumLineError::BadStamp { .. }));

        let (line, err, msg) = line_error(&format!("{good}2.0 0 0 0 0 0 0 2\n"));
        assert_eq!(line, 3);
        assert_eq!(err, TumLineError::NotUnitQuaternion { norm: 2.0 });
        assert!(msg.contains("columns 5-8"), "{msg}");
    }

    #[test]
    fn missing_file_is_an_io_error_naming_it() {
        let err = read_tum("/nonexistent/dir/x.tum").unwrap_err();
        assert!(matches!(err, TumError::Io { .. }));
        assert!(err.to_string().starts_with("/nonexistent/dir/x.tum: "));
    }

    #[test]
    fn write_tum_refuses_non_finite_and_round_trips_through_a_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.tum");
        let mut traj = Trajectory::new();
        traj.push(sample(5, [1.0 / 3.0, 2e-300, -7e20], [0.1, 0.2, 0.3, 0.9]));
        traj.push(sample(6, [0.0, -0.0, 1.0], [0.0, 0.0, 0.0, 1.0]));
        write_tum(&path, &traj).unwrap();
        let back = read_tum(&path).unwrap();
        assert_eq!(back, traj);
        traj.samples[1].world_from_body.translation.x = f64::NAN;
        let err = write_tum(&path, &traj).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
    }
}
