//! Fault injection on the `vinebench` binary: signals at several points of a run, a
//! killed run, a full disk, a read-only folder, two runs racing for one folder, a closed
//! or full stdout, scenarios sharing a name. Each checks that nothing is lost: the
//! recording is finalized (or recovers its complete chunks), the outputs are whole or
//! absent, the error names the cause and the exit code says what `--help` promises.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_vinebench");

/// Five laps around a 20 m row: long enough (seconds of wall time) to be interrupted.
const LONG: &str = "name = \"fault-long\"\nseed = 3\nmax_duration_s = 900.0\n\
    [world.rows]\ncount = 2\nlength_m = 20.0\n[route.row_loop]\nrow = 0\nlaps = 5\n";

fn vinebench() -> Command {
    Command::new(BIN)
}

/// `vinebench run SCENARIO --out OUT --quiet`.
fn run_cmd(scenario: &Path, out: &Path) -> Command {
    let mut c = vinebench();
    c.arg("run")
        .arg(scenario)
        .arg("--out")
        .arg(out)
        .arg("--quiet");
    c
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Waits until `path` exists with at least `bytes` bytes (or the child exits).
fn wait_for_file(child: &mut Child, path: &Path, bytes: u64) {
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(120) {
        if std::fs::metadata(path).is_ok_and(|m| m.len() >= bytes) {
            return;
        }
        if child.try_wait().unwrap().is_some() {
            panic!("the run ended before {} had {bytes} bytes", path.display());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    panic!("{} never reached {bytes} bytes", path.display());
}

fn signal(child: &Child, sig: &str) {
    let st = Command::new("kill")
        .args([format!("-{sig}"), child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success(), "kill -{sig}");
}

/// The poses of a TUM file as lines (stamp first).
fn tum_lines(p: &Path) -> Vec<String> {
    std::fs::read_to_string(p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(str::to_string)
        .collect()
}

/// The uninterrupted run of [`LONG`]: its EIF estimate.
fn full_run(dir: &Path) -> Vec<String> {
    let sc = write(dir, "long.toml", LONG);
    let out = dir.join("full");
    let o = run_cmd(&sc, &out).output().unwrap();
    assert!(matches!(o.status.code(), Some(0 | 1)), "{}", stderr(&o));
    tum_lines(&out.join("estimate_eif.tum"))
}

/// Replays `recording` and returns its EIF estimate; the replay must find poses.
fn replay(recording: &Path, out: &Path) -> (Output, Vec<String>) {
    let o = vinebench()
        .args([
            "replay",
            recording.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        matches!(o.status.code(), Some(0 | 1)),
        "replay of {}: {}",
        recording.display(),
        stderr(&o)
    );
    let lines = tum_lines(&out.join("estimate_eif.tum"));
    (o, lines)
}

/// The stamp of a TUM line.
fn stamp(line: &str) -> f64 {
    line.split_whitespace()
        .next()
        .and_then(|t| t.parse().ok())
        .unwrap_or(f64::NAN)
}

/// How much of the end of a cut stream may legitimately differ from the live run: the
/// estimator re-orders messages within `reorder_window_ms` (150 ms) and sensors arrive
/// up to their latency late, so at the cut the replay flushes what the live run would
/// still have interleaved with later messages.
const CUT_TAIL_S: f64 = 1.0;

/// `part` equals `full` pose for pose up to [`CUT_TAIL_S`] before its end, and is shorter.
fn assert_prefix(part: &[String], full: &[String], what: &str) {
    assert!(!part.is_empty(), "{what}: no poses");
    assert!(
        part.len() < full.len(),
        "{what}: {} poses, the full run has {}: the cut did not cut",
        part.len(),
        full.len()
    );
    let end = stamp(&part[part.len() - 1]) - CUT_TAIL_S;
    let compared = part.iter().take_while(|l| stamp(l) <= end).count();
    assert!(
        compared > 0,
        "{what}: the cut came before any comparable pose"
    );
    for (i, (a, b)) in part.iter().zip(full).take(compared).enumerate() {
        assert_eq!(
            a,
            b,
            "{what}: pose {i} of {} differs from the live run's",
            part.len()
        );
    }
}

#[test]
fn sigint_and_sigterm_finalize_the_recording_and_replay_equals_the_live_run() {
    let tmp = tempfile::tempdir().unwrap();
    let full = full_run(tmp.path());
    let sc = write(tmp.path(), "long.toml", LONG);
    // Cut points: as soon as the recording has its first chunk, and later in the run.
    for (k, (sig, after_bytes)) in [("INT", 1), ("TERM", 1), ("TERM", 400_000)]
        .into_iter()
        .enumerate()
    {
        let out = tmp.path().join(format!("cut-{k}"));
        let mut child = run_cmd(&sc, &out).stderr(Stdio::piped()).spawn().unwrap();
        let rec = out.join("recording.mcap");
        wait_for_file(&mut child, &rec, after_bytes);
        signal(&child, sig);
        let o = child.wait_with_output().unwrap();
        assert_eq!(o.status.code(), Some(130), "SIG{sig}: {}", stderr(&o));
        assert!(stderr(&o).contains("finalized"), "SIG{sig}: {}", stderr(&o));
        // Finalized: the replay reports no damage.
        let (r, lines) = replay(&rec, &tmp.path().join(format!("cut-{k}-replay")));
        assert!(
            !stderr(&r).contains("damaged"),
            "SIG{sig}: the recording was not finalized: {}",
            stderr(&r)
        );
        assert_prefix(&lines, &full, &format!("SIG{sig} at {after_bytes} bytes"));
        // The interrupted run released its folder.
        assert!(!out.join(".vinebench.lock").exists());
    }
}

#[test]
fn a_killed_run_replays_every_complete_chunk() {
    let tmp = tempfile::tempdir().unwrap();
    let full = full_run(tmp.path());
    let sc = write(tmp.path(), "long.toml", LONG);
    let out = tmp.path().join("killed");
    let mut child = run_cmd(&sc, &out).spawn().unwrap();
    let rec = out.join("recording.mcap");
    wait_for_file(&mut child, &rec, 400_000);
    signal(&child, "KILL");
    child.wait().unwrap();
    let (r, lines) = replay(&rec, &tmp.path().join("killed-replay"));
    assert!(
        stderr(&r).contains("not finalized"),
        "a killed run's recording has no footer: {}",
        stderr(&r)
    );
    assert_prefix(&lines, &full, "SIGKILL");
    // A later run into the killed run's folder takes over its stale lock.
    let o = vinebench()
        .args([
            "run",
            sc.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--replace",
        ])
        .args(["--quiet"])
        .output()
        .unwrap();
    assert!(matches!(o.status.code(), Some(0 | 1)), "{}", stderr(&o));
    assert_eq!(tum_lines(&out.join("estimate_eif.tum")), full);
}

#[test]
fn a_full_disk_stops_the_run_names_the_cause_and_leaves_no_partial_output() {
    // RLIMIT_FSIZE stands in for a full disk without root: a write past the limit fails
    // (EFBIG) as a full disk's (ENOSPC) does; SIGXFSZ is ignored so the write returns the
    // error instead of killing the process.
    let tmp = tempfile::tempdir().unwrap();
    let sc = write(tmp.path(), "long.toml", LONG);
    let out = tmp.path().join("full-disk");
    let o = Command::new("bash")
        .args([
            "-c",
            &format!(
                "trap '' XFSZ; ulimit -f 256; exec {BIN} run {} --out {} --quiet",
                sc.display(),
                out.display()
            ),
        ])
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("File too large"), "the cause is named: {err}");
    assert!(!err.contains("attempted another write"), "{err}");
    // It stopped at the first failed write: no trajectory or report was written from a run
    // whose recording failed, and nothing half-written is left.
    for f in [
        "ground_truth.tum",
        "estimate_eif.tum",
        "report.json",
        "report.md",
    ] {
        assert!(
            !out.join(f).exists(),
            "{f} written after the recording failed"
        );
    }
    for e in std::fs::read_dir(&out).unwrap() {
        let n = e.unwrap().file_name().into_string().unwrap();
        assert!(!n.contains(".tmp"), "temporary file {n} left behind");
    }
}

#[test]
fn a_read_only_folder_is_an_error_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let sc = write(
        tmp.path(),
        "s.toml",
        "name = \"ro\"\nmax_duration_s = 5.0\n",
    );
    let ro = tmp.path().join("ro");
    std::fs::create_dir(&ro).unwrap();
    let mut perm = std::fs::metadata(&ro).unwrap().permissions();
    std::os::unix::fs::PermissionsExt::set_mode(&mut perm, 0o555);
    std::fs::set_permissions(&ro, perm).unwrap();
    // Root writes anywhere; /proc/<pid>/ is read-only for everyone.
    let is_root = std::fs::write(ro.join("probe"), "x").is_ok();
    let out = if is_root {
        PathBuf::from(format!("/proc/{}/vinebench-run", std::process::id()))
    } else {
        ro.join("run")
    };
    let o = run_cmd(&sc, &out).output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains(out.to_str().unwrap()),
        "names the folder: {err}"
    );
    assert_eq!(
        err.matches("os error").count(),
        1,
        "the OS error said once: {err}"
    );
}

#[test]
fn two_runs_racing_for_one_folder_one_wins_and_its_recording_is_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let sc = write(
        tmp.path(),
        "s.toml",
        "name = \"race\"\nmax_duration_s = 30.0\n[motion]\nmodel = \"kinematic\"\n",
    );
    let out = tmp.path().join("shared");
    let spawn = || run_cmd(&sc, &out).stderr(Stdio::piped()).spawn().unwrap();
    let (a, b) = (spawn(), spawn());
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    let codes = [a.status.code(), b.status.code()];
    let losers: Vec<&Output> = [&a, &b]
        .into_iter()
        .filter(|o| o.status.code() == Some(2))
        .collect();
    assert_eq!(losers.len(), 1, "exactly one run is refused: {codes:?}");
    let msg = stderr(losers[0]);
    assert!(
        msg.contains("in use by another run") || msg.contains("not empty"),
        "{msg}"
    );
    // The winner's recording is intact.
    let (r, lines) = replay(&out.join("recording.mcap"), &tmp.path().join("replay"));
    assert!(!stderr(&r).contains("damaged"), "{}", stderr(&r));
    assert_eq!(lines, tum_lines(&out.join("estimate_eif.tum")));
    // Running again into the used folder is refused, then replaced on request.
    let again = run_cmd(&sc, &out).output().unwrap();
    assert_eq!(again.status.code(), Some(2));
    assert!(stderr(&again).contains("--replace"), "{}", stderr(&again));
    // A replay's folder is owned the same way.
    let rec = out.join("recording.mcap");
    let dest = tmp.path().join("replay");
    let o = vinebench()
        .arg("replay")
        .arg(&rec)
        .arg("--out")
        .arg(&dest)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("not empty"), "{}", stderr(&o));
    let o = vinebench()
        .arg("replay")
        .arg(&rec)
        .arg("--out")
        .arg(&dest)
        .arg("--replace")
        .output()
        .unwrap();
    assert!(matches!(o.status.code(), Some(0 | 1)), "{}", stderr(&o));
    assert_eq!(lines, tum_lines(&dest.join("estimate_eif.tum")));
}

#[test]
fn scenarios_sharing_a_name_get_their_own_folders() {
    let tmp = tempfile::tempdir().unwrap();
    let body = "name = \"same\"\nmax_duration_s = 3.0\n[motion]\nmodel = \"kinematic\"\n";
    for k in 0..3 {
        write(tmp.path(), &format!("s{k}.toml"), body);
    }
    let runs = tmp.path().join("runs");
    let o = vinebench()
        .args([
            "check",
            tmp.path().to_str().unwrap(),
            "--runs",
            runs.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(matches!(o.status.code(), Some(0 | 1)), "{}", stderr(&o));
    let folders: Vec<_> = std::fs::read_dir(&runs).unwrap().collect();
    assert_eq!(folders.len(), 3, "one folder per run");
    for f in folders {
        let f = f.unwrap().path();
        assert!(f.join("recording.mcap").exists() && f.join("report.json").exists());
    }
}

#[test]
fn an_empty_shard_is_a_success_with_nothing_to_do() {
    let tmp = tempfile::tempdir().unwrap();
    write(
        tmp.path(),
        "a.toml",
        "name = \"a\"\nmax_duration_s = 2.0\n[motion]\nmodel = \"kinematic\"\n",
    );
    let junit = tmp.path().join("j.xml");
    let o = vinebench()
        .args(["check", tmp.path().to_str().unwrap(), "--shard", "3/3"])
        .args(["--runs", tmp.path().join("runs").to_str().unwrap()])
        .args(["--junit", junit.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(stderr(&o).contains("nothing to do"), "{}", stderr(&o));
    assert!(
        std::fs::read_to_string(&junit)
            .unwrap()
            .contains("tests=\"0\"")
    );
}

#[test]
fn a_closed_pipe_is_quiet_and_a_full_stdout_is_an_error() {
    let tmp = tempfile::tempdir().unwrap();
    let sc = write(tmp.path(), "s.toml", "name = \"pipe\"\n");
    for args in [
        vec!["defaults"],
        vec!["validate", sc.to_str().unwrap(), sc.to_str().unwrap()],
        vec!["--help"],
    ] {
        // The reader is gone before the first write.
        let mut child = vinebench()
            .args(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        assert!(!stderr(&o).contains("panicked"), "{args:?}: {}", stderr(&o));
        if args[0] != "--help" {
            // clap prints --help itself; ours keep their exit codes.
            assert_eq!(o.status.code(), Some(0), "{args:?}: {}", stderr(&o));
        }
        // A full device.
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let o = vinebench().args(&args).stdout(full).output().unwrap();
        assert!(!stderr(&o).contains("panicked"), "{args:?}: {}", stderr(&o));
        if args[0] != "--help" {
            assert_eq!(o.status.code(), Some(2), "{args:?}");
            assert!(
                stderr(&o).contains("No space left on device"),
                "{}",
                stderr(&o)
            );
        }
    }
}

#[test]
fn bad_numbers_and_sizes_on_the_command_line_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let t = write(tmp.path(), "a.tum", "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n");
    for bad in ["nan", "inf", "-1"] {
        let o = vinebench()
            .args(["score", "--ref", t.to_str().unwrap(), t.to_str().unwrap()])
            .arg(format!("--t-max-diff={bad}"))
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "--t-max-diff {bad}");
        assert!(stderr(&o).contains("--t-max-diff"), "{}", stderr(&o));
    }
    let o = vinebench()
        .args(["--threads", "100000", "defaults"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("1..=1024"), "{}", stderr(&o));
    // An endless scenario file.
    let o = vinebench()
        .args(["validate", "/dev/zero"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("larger than 16 MiB"), "{}", stderr(&o));
    // Start times whose run would not fit in 64-bit nanoseconds.
    for t in ["2262-01-01T00:00:00Z", "9999-12-31T23:59:59Z"] {
        let sc = write(tmp.path(), "t.toml", &format!("start_time_utc = \"{t}\"\n"));
        let o = vinebench()
            .args(["validate", sc.to_str().unwrap()])
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{t}");
        assert!(
            stderr(&o).contains("to 2200-01-01T00:00:00Z"),
            "{}",
            stderr(&o)
        );
    }
}
