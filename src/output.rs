//! Standard output that never panics: `vinebench validate x.toml | head -1` or
//! `vinebench defaults > /dev/full` must not crash the tool (Rust's `println!` panics on a
//! failed write).
//!
//! [`outln!`](crate::outln) and [`out!`](crate::out) write to stdout. A closed pipe
//! (`EPIPE`) silences every later write, as Unix filters expect: the reader has what it
//! wanted, the command still finishes its work and its exit code keeps its meaning. Any
//! other failure (a full disk, an I/O error) is kept; [`error`] returns it so `main` can
//! report it and exit non-zero.

use std::io::Write;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

static CLOSED: AtomicBool = AtomicBool::new(false);
static FAILED: OnceLock<String> = OnceLock::new();

/// Writes `args` to stdout and flushes; see the [module docs](self) for errors.
pub fn write(args: std::fmt::Arguments<'_>) {
    if CLOSED.load(Ordering::Relaxed) || FAILED.get().is_some() {
        return;
    }
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|()| out.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            CLOSED.store(true, Ordering::Relaxed);
        } else {
            let _ = FAILED.set(e.to_string());
        }
    }
}

/// The first write error other than a closed pipe, if any.
pub fn error() -> Option<&'static str> {
    FAILED.get().map(String::as_str)
}

/// True when the reader closed stdout.
pub fn closed() -> bool {
    CLOSED.load(Ordering::Relaxed)
}

/// `println!` that does not panic (see [`crate::output`]).
#[macro_export]
macro_rules! outln {
    () => {
        $crate::output::write(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::output::write(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `print!` that does not panic (see [`crate::output`]).
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::output::write(format_args!($($arg)*))
    };
}
