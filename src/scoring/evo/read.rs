//! Trajectory files as evo 1.38.1 reads them: TUM (`t x y z qx qy qz qw`), KITTI poses
//! (a row-major 3×4 `[R|t]` per line; optionally with a times file, one stamp per line, as
//! KITTI odometry ships `times.txt`), EuRoC ground-truth CSV (`timestamp [ns], p, q_wxyz,
//! ...`). Lines starting with `#` are comments; a UTF-8 byte-order mark is skipped. Stamps
//! may repeat or go backwards, as evo allows (association then decides which poses are
//! used; [`super::sync`] says how many were left out). Unlike evo, fields may be separated
//! by any run of spaces or tabs, blank lines are skipped, and a non-finite value is an
//! error naming the line and column (evo would carry a NaN into the statistics).

use super::{Format, Traj, lie};
use nalgebra::{Matrix3, Vector3};
use std::path::Path;

/// Why a trajectory file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// A line is not what the format expects.
    #[error("{path}:{line}: {problem} (reading it as {format}: {expected}){hint}")]
    Line {
        /// The file.
        path: String,
        /// 1-based line.
        line: usize,
        /// The format it was read as.
        format: Format,
        /// What the format expects.
        expected: &'static str,
        /// What is wrong.
        problem: String,
        /// Which format the line looks like instead, if any.
        hint: String,
    },
    /// No pose at all.
    #[error("{path}: no poses (reading it as {format}: {expected})")]
    Empty {
        /// The file.
        path: String,
        /// The format.
        format: Format,
        /// What it expects.
        expected: &'static str,
    },
    /// A KITTI times file does not fit its poses.
    #[error("{path}: {problem}")]
    Times {
        /// The times file.
        path: String,
        /// What is wrong.
        problem: String,
    },
}

/// What each format expects of a line.
fn expected(format: Format) -> &'static str {
    match format {
        Format::Tum => "8 numbers per line: timestamp x y z qx qy qz qw",
        Format::Kitti => "12 numbers per line: a row-major 3x4 [R|t]",
        Format::Euroc => {
            "at least 8 comma-separated numbers per line: timestamp [ns], p_x, p_y, p_z, q_w, \
             q_x, q_y, q_z"
        }
        Format::Mcap => "a pose topic of a ROS 2 recording",
    }
}

/// Which format a line with `fields` fields looks like (for the error's hint).
fn looks_like(body: &str, format: Format) -> String {
    let commas = body.split(',').count();
    let spaces = body.split_ascii_whitespace().count();
    let guess = if commas >= 8 {
        Some("a EuRoC CSV (use `euroc`)")
    } else if spaces == 12 {
        Some("a KITTI pose file (use `kitti`)")
    } else if spaces == 8 {
        Some("a TUM file (use `tum`)")
    } else {
        None
    };
    match guess {
        Some(g) if !g.contains(&format!("`{}`", format.name())) => format!("; it looks like {g}"),
        _ => String::new(),
    }
}

/// The lines of a file that carry data: `(1-based line, text)`.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.starts_with('#') && !l.trim().is_empty())
        .map(|(i, l)| (i + 1, l.trim()))
}

fn read_text(path: &Path) -> Result<String, ReadError> {
    crate::fsio::read_text_bounded(path, crate::fsio::MAX_TUM_BYTES).map_err(|source| {
        ReadError::Io {
            path: path.display().to_string(),
            source,
        }
    })
}

/// Parses the numbers of one line, all finite.
fn numbers(
    path: &Path,
    line: usize,
    body: &str,
    format: Format,
    fields: Vec<&str>,
    count_ok: impl Fn(usize) -> bool,
) -> Result<Vec<f64>, ReadError> {
    let err = |problem: String| ReadError::Line {
        path: path.display().to_string(),
        line,
        format,
        expected: expected(format),
        problem,
        hint: looks_like(body, format),
    };
    if !count_ok(fields.len()) {
        return Err(err(format!("{} fields", fields.len())));
    }
    fields
        .iter()
        .enumerate()
        .map(|(k, f)| match f.trim().parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(err(format!("column {} is not finite: {f:?}", k + 1))),
            Err(_) => Err(err(format!("column {} is not a number: {f:?}", k + 1))),
        })
        .collect()
}

/// Reads `path` as `format` (a KITTI file optionally with `times`, one stamp in seconds
/// per pose).
pub fn read(path: &Path, format: Format, times: Option<&Path>) -> Result<Traj, ReadError> {
    let text = read_text(path)?;
    let name = path.display().to_string();
    let mut stamps = Vec::new();
    let mut poses = Vec::new();
    for (line, body) in data_lines(&text) {
        match format {
            Format::Tum => {
                let f = body.split_ascii_whitespace().collect();
                let v = numbers(path, line, body, format, f, |n| n == 8)?;
                stamps.push(v[0]);
                let r = lie::quaternion_matrix(v[7], v[4], v[5], v[6]);
                poses.push(lie::se3(&r, &Vector3::new(v[1], v[2], v[3])));
            }
            Format::Kitti => {
                let f = body.split_ascii_whitespace().collect();
                let v = numbers(path, line, body, format, f, |n| n == 12)?;
                let r = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
                poses.push(lie::se3(&r, &Vector3::new(v[3], v[7], v[11])));
            }
            Format::Mcap => {
                return Err(ReadError::Empty {
                    path: name,
                    format,
                    expected: expected(format),
                });
            }
            Format::Euroc => {
                let f = body.split(',').collect();
                let v = numbers(path, line, body, format, f, |n| n >= 8)?;
                // evo: the nanosecond integer parsed as a double, then divided by 1e9.
                stamps.push(v[0] / 1e9);
                let r = lie::quaternion_matrix(v[4], v[5], v[6], v[7]);
                poses.push(lie::se3(&r, &Vector3::new(v[1], v[2], v[3])));
            }
        }
    }
    if poses.is_empty() {
        return Err(ReadError::Empty {
            path: name,
            format,
            expected: expected(format),
        });
    }
    let stamps = match (format, times) {
        (Format::Kitti, None) => None,
        (Format::Kitti, Some(t)) => Some(read_times(t, poses.len())?),
        _ => Some(stamps),
    };
    Ok(Traj {
        name,
        format,
        stamps,
        poses,
    })
}

/// A KITTI times file: one stamp (s) per pose.
fn read_times(path: &Path, n: usize) -> Result<Vec<f64>, ReadError> {
    let text = read_text(path)?;
    let mut out = Vec::with_capacity(n);
    for (line, body) in data_lines(&text) {
        let v = body.parse::<f64>().ok().filter(|v| v.is_finite());
        let Some(v) = v else {
            return Err(ReadError::Times {
                path: path.display().to_string(),
                problem: format!("line {line}: expected one stamp in seconds, found {body:?}"),
            });
        };
        out.push(v);
    }
    if out.len() != n {
        return Err(ReadError::Times {
            path: path.display().to_string(),
            problem: format!("{} stamps for {n} poses (expected one per pose)", out.len()),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(text: &str) -> tempfile::NamedTempFile {
        let f = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(f.path(), text).unwrap();
        f
    }

    #[test]
    fn the_three_formats_give_the_same_pose() {
        // 90° about z at (1, 2, 3), stamp 1.5 s.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let tum = write(&format!("# t x y z qx qy qz qw\n1.5 1 2 3 0 0 {h} {h}\n"));
        let kitti = write("0 -1 0 1 1 0 0 2 0 0 1 3\n");
        let euroc = write(&format!(
            "#timestamp,p,q\n1500000000,1,2,3,{h},0,0,{h},9,9\n"
        ));
        let a = read(tum.path(), Format::Tum, None).unwrap();
        let b = read(kitti.path(), Format::Kitti, None).unwrap();
        let c = read(euroc.path(), Format::Euroc, None).unwrap();
        assert_eq!(a.stamps, Some(vec![1.5]));
        assert_eq!(b.stamps, None);
        assert_eq!(c.stamps, Some(vec![1.5]));
        assert!((a.poses[0] - b.poses[0]).amax() < 1e-15);
        assert!((c.poses[0] - b.poses[0]).amax() < 1e-15);
    }

    #[test]
    fn duplicate_and_backward_stamps_are_read_as_evo_reads_them() {
        let f = write("1 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n0.5 2 0 0 0 0 0 1\n");
        let t = read(f.path(), Format::Tum, None).unwrap();
        assert_eq!(t.stamps, Some(vec![1.0, 1.0, 0.5]));
    }

    #[test]
    fn errors_name_the_line_the_format_and_what_it_looks_like() {
        let f = write("0 -1 0 1 1 0 0 2 0 0 1 3\n");
        let e = read(f.path(), Format::Tum, None).unwrap_err().to_string();
        assert!(
            e.contains(":1: 12 fields") && e.contains("as TUM") && e.contains("KITTI"),
            "{e}"
        );
        let f = write("1 0 0 0 0 0 0 1\n2 0 0 nan 0 0 0 1\n");
        let e = read(f.path(), Format::Tum, None).unwrap_err().to_string();
        assert!(e.contains(":2: column 4 is not finite"), "{e}");
        let f = write("# nothing\n");
        let e = read(f.path(), Format::Euroc, None).unwrap_err().to_string();
        assert!(e.contains("no poses") && e.contains("EuRoC"), "{e}");
        let poses = write("1 0 0 0 0 1 0 0 0 0 1 0\n");
        let times = write("0.0\n0.1\n");
        let e = read(poses.path(), Format::Kitti, Some(times.path()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("2 stamps for 1 poses"), "{e}");
    }
}
