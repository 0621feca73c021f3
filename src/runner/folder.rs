//! A run folder is owned by one run.
//!
//! [`RunFolder::claim`] takes a folder for a run before anything is written to it:
//! - a generated name (`runs/<name>-<UTC stamp>`) is made unique by creating the folder
//!   itself (`-2`, `-3`, ... on a clash), so scenarios sharing a name that start in the same
//!   second never share a folder;
//! - every run folder holds a lock file ([`LOCK_FILE`], created exclusively, naming the
//!   process and host) for as long as the run lasts: a second run into the same `--out`
//!   is refused while the first is alive; a lock left by a killed process (same host, the
//!   process gone) is taken over;
//! - a folder that already holds files is refused, unless the caller says to replace it:
//!   then the files a run writes ([`is_run_output`]) are removed first, and anything else
//!   in the folder is left alone, so a re-used `--out` never mixes two runs' outputs.

use super::outcome::{RunError, io_err};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The lock file in a run folder while a run writes it.
pub const LOCK_FILE: &str = ".vinebench.lock";

/// How many `-2`, `-3`, ... suffixes a generated folder name tries.
const MAX_NAME_SUFFIX: u32 = 10_000;

/// A run folder claimed by this process; dropping it releases the lock.
#[derive(Debug)]
pub struct RunFolder {
    dir: PathBuf,
    lock: PathBuf,
}

impl RunFolder {
    /// Claims `out` (`None`: a new folder `<runs_root>/<name>-<stamp>`); see the
    /// [module docs](self).
    pub fn claim(
        out: Option<&Path>,
        runs_root: &Path,
        name: &str,
        stamp: &str,
        replace: bool,
    ) -> Result<RunFolder, RunError> {
        let dir = match out {
            Some(d) => {
                std::fs::create_dir_all(d).map_err(io_err(d))?;
                d.to_path_buf()
            }
            None => unique_folder(runs_root, &format!("{name}-{stamp}"))?,
        };
        let lock = dir.join(LOCK_FILE);
        take_lock(&lock)?;
        let folder = RunFolder { dir, lock };
        let others = folder.entries()?;
        if !others.is_empty() {
            if !replace {
                let shown: Vec<&str> = others.iter().take(5).map(String::as_str).collect();
                return Err(RunError::FolderNotEmpty {
                    path: folder.dir.display().to_string(),
                    entries: others.len(),
                    first: shown.join(", "),
                });
            }
            for e in others.iter().filter(|e| is_run_output(e)) {
                let p = folder.dir.join(e);
                let removed = if p.is_dir() {
                    std::fs::remove_dir_all(&p)
                } else {
                    std::fs::remove_file(&p)
                };
                removed.map_err(io_err(&p))?;
            }
        }
        Ok(folder)
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// Names in the folder other than the lock, sorted.
    fn entries(&self) -> Result<Vec<String>, RunError> {
        let mut names: Vec<String> = std::fs::read_dir(&self.dir)
            .map_err(io_err(&self.dir))?
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n != LOCK_FILE)
            .collect();
        names.sort();
        Ok(names)
    }
}

impl Drop for RunFolder {
    fn drop(&mut self) {
        // Best effort: the folder may have been removed (a sweep's discarded job).
        let _ = std::fs::remove_file(&self.lock);
    }
}

/// True for the names a run writes into its folder (what `--replace` clears).
pub fn is_run_output(name: &str) -> bool {
    matches!(
        name,
        "recording.mcap"
            | "scenario.resolved.toml"
            | "report.json"
            | "report.md"
            | "timing.json"
            | "loops.csv"
            | "images"
            | "map"
    ) || name.ends_with(".svg")
        || (name.ends_with(".tum")
            && (name.starts_with("ground_truth") || name.starts_with("estimate_")))
        || (name.starts_with('.') && name.contains(".tmp"))
}

/// Creates `<root>/<base>`, or `<root>/<base>-2`, ... when taken.
fn unique_folder(root: &Path, base: &str) -> Result<PathBuf, RunError> {
    std::fs::create_dir_all(root).map_err(io_err(root))?;
    for k in 1..=MAX_NAME_SUFFIX {
        let p = if k == 1 {
            root.join(base)
        } else {
            root.join(format!("{base}-{k}"))
        };
        match std::fs::create_dir(&p) {
            Ok(()) => return Ok(p),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(io_err(&p)(e)),
        }
    }
    Err(RunError::Io {
        path: root.join(base).display().to_string(),
        source: std::io::Error::new(
            std::io::ErrorKind::AlreadyExists,
            format!("{MAX_NAME_SUFFIX} folders of that name exist; clean up the runs folder"),
        ),
    })
}

/// This host's name (for the lock's owner).
fn host() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|_| "unknown".into())
}

/// Creates the lock exclusively; takes over a stale one (same host, process gone).
fn take_lock(lock: &Path) -> Result<(), RunError> {
    let me = format!("pid {} on {}\n", std::process::id(), host());
    for attempt in 0..2 {
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(lock)
        {
            Ok(mut f) => {
                f.write_all(me.as_bytes()).map_err(io_err(lock))?;
                return Ok(());
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let owner = std::fs::read_to_string(lock).unwrap_or_default();
                let owner = owner.trim();
                if attempt == 0 && is_stale(owner) {
                    let _ = std::fs::remove_file(lock);
                    continue;
                }
                return Err(RunError::FolderInUse {
                    path: lock
                        .parent()
                        .map(|p| p.display().to_string())
                        .unwrap_or_default(),
                    owner: if owner.is_empty() {
                        "another run".into()
                    } else {
                        owner.to_string()
                    },
                });
            }
            Err(e) => return Err(io_err(lock)(e)),
        }
    }
    Err(RunError::FolderInUse {
        path: lock
            .parent()
            .map(|p| p.display().to_string())
            .unwrap_or_default(),
        owner: "another run".into(),
    })
}

/// A lock `pid N on HOST` whose process no longer exists on this host.
fn is_stale(owner: &str) -> bool {
    let Some((pid, on)) = owner
        .strip_prefix("pid ")
        .and_then(|r| r.split_once(" on "))
    else {
        return false;
    };
    let Ok(pid) = pid.parse::<u32>() else {
        return false;
    };
    on == host()
        && Path::new("/proc").exists()
        && !Path::new("/proc").join(pid.to_string()).exists()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generated_names_are_unique_within_a_second() {
        let root = tempfile::tempdir().unwrap();
        let a = RunFolder::claim(None, root.path(), "x", "20260101-000000", false).unwrap();
        let b = RunFolder::claim(None, root.path(), "x", "20260101-000000", false).unwrap();
        assert_ne!(a.path(), b.path());
        assert!(b.path().ends_with("x-20260101-000000-2"));
    }

    #[test]
    fn a_folder_in_use_is_refused_and_released_on_drop() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("run");
        let a = RunFolder::claim(Some(&out), root.path(), "x", "s", false).unwrap();
        let e = RunFolder::claim(Some(&out), root.path(), "x", "s", true).unwrap_err();
        assert!(matches!(e, RunError::FolderInUse { .. }), "{e}");
        assert!(
            e.to_string()
                .contains(&format!("pid {}", std::process::id())),
            "{e}"
        );
        drop(a);
        assert!(!out.join(LOCK_FILE).exists());
        RunFolder::claim(Some(&out), root.path(), "x", "s", false).unwrap();
    }

    #[test]
    fn a_stale_lock_is_taken_over() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("run");
        std::fs::create_dir_all(&out).unwrap();
        // No process has pid 2^31 - 1 (Linux pids are at most 2^22).
        std::fs::write(
            out.join(LOCK_FILE),
            format!("pid 2147483647 on {}\n", host()),
        )
        .unwrap();
        RunFolder::claim(Some(&out), root.path(), "x", "s", false).unwrap();
        // A lock from another host is never taken over.
        std::fs::write(out.join(LOCK_FILE), "pid 2147483647 on elsewhere\n").unwrap();
        let e = RunFolder::claim(Some(&out), root.path(), "x", "s", false).unwrap_err();
        assert!(e.to_string().contains("elsewhere"), "{e}");
    }

    #[test]
    fn a_non_empty_folder_is_refused_unless_replaced_and_only_ours_is_cleared() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("run");
        std::fs::create_dir_all(out.join("map")).unwrap();
        for f in ["estimate_eif.tum", "report.md", "notes.txt", "map/map.ply"] {
            std::fs::write(out.join(f), "x").unwrap();
        }
        let e = RunFolder::claim(Some(&out), root.path(), "x", "s", false).unwrap_err();
        assert!(
            matches!(e, RunError::FolderNotEmpty { entries: 4, .. }),
            "{e}"
        );
        assert!(e.to_string().contains("--replace"), "{e}");
        // Refusing leaves everything, the lock included, as it was.
        assert!(out.join("estimate_eif.tum").exists() && !out.join(LOCK_FILE).exists());
        let f = RunFolder::claim(Some(&out), root.path(), "x", "s", true).unwrap();
        let mut left: Vec<_> = std::fs::read_dir(f.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        left.sort();
        assert_eq!(left, [LOCK_FILE, "notes.txt"]);
    }
}
