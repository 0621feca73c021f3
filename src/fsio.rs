//! Whole-or-nothing file writes (a reader never sees half a file) and bounded reads (an
//! input file, or `/dev/zero` given as one, never takes more memory than its stated limit).

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// The largest scenario file vinebench reads: 16 MiB, hundreds of times the largest real
/// one (sweep files and topic mappings have their own, smaller bounds).
pub const MAX_SCENARIO_BYTES: u64 = 16 << 20;

/// The largest TUM trajectory file read whole: 2 GiB.
pub const MAX_TUM_BYTES: u64 = 2 << 30;

/// The largest world mesh (PLY or OBJ) read: 2 GiB.
pub const MAX_MESH_BYTES: u64 = 2 << 30;

/// Checks that `path` is a regular file of at most `limit` bytes, for inputs that a
/// parser streams rather than reading whole (meshes): a device such as `/dev/zero`, a
/// pipe or a folder is refused ([`std::io::ErrorKind::InvalidInput`]), a larger file is
/// [`std::io::ErrorKind::FileTooLarge`] saying the limit.
pub fn check_input_file(path: &Path, limit: u64) -> std::io::Result<()> {
    let m = std::fs::metadata(path)?;
    if !m.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "expected a regular file, found a folder, device or pipe",
        ));
    }
    if m.len() > limit {
        return Err(std::io::Error::new(
            std::io::ErrorKind::FileTooLarge,
            format!(
                "the file is {} bytes, larger than {}",
                m.len(),
                human_bytes(limit)
            ),
        ));
    }
    Ok(())
}

/// Reads a whole file of at most `limit` bytes; a longer one (or an endless one, such as
/// `/dev/zero`) is an [`std::io::ErrorKind::FileTooLarge`] error saying the limit, read
/// without holding more than `limit + 1` bytes.
pub fn read_bounded(path: &Path, limit: u64) -> std::io::Result<Vec<u8>> {
    let f = std::fs::File::open(path)?;
    if f.metadata().is_ok_and(|m| m.is_dir()) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::IsADirectory,
            "expected a file, found a folder",
        ));
    }
    let mut bytes = Vec::new();
    f.take(limit + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(too_large(limit));
    }
    Ok(bytes)
}

/// [`read_bounded`] as UTF-8 text; invalid UTF-8 is an
/// [`std::io::ErrorKind::InvalidData`] error naming the byte offset.
pub fn read_text_bounded(path: &Path, limit: u64) -> std::io::Result<String> {
    let bytes = read_bounded(path, limit)?;
    String::from_utf8(bytes).map_err(|e| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "expected UTF-8 text, found an invalid byte at offset {}",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

fn too_large(limit: u64) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::FileTooLarge,
        format!(
            "larger than {} (the limit for this kind of input)",
            human_bytes(limit)
        ),
    )
}

/// `16 MiB`, `2 GiB`, `512 bytes`.
pub fn human_bytes(n: u64) -> String {
    if n >= 1 << 30 && n.is_multiple_of(1 << 30) {
        format!("{} GiB", n >> 30)
    } else if n >= 1 << 20 && n.is_multiple_of(1 << 20) {
        format!("{} MiB", n >> 20)
    } else if n >= 1 << 10 && n.is_multiple_of(1 << 10) {
        format!("{} KiB", n >> 10)
    } else {
        format!("{n} bytes")
    }
}

/// Writes `bytes` to `path` through a synced temporary file beside it and a rename, so
/// the file is either the old one or the complete new one, also after a crash or a full
/// disk. The parent folder is created.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// [`write_atomic`] for content produced by `write` as a stream (through a buffer), so a
/// large file (a long run's ground truth) is never whole in memory. An error of `write`
/// leaves the old file, or none.
pub fn write_atomic_with(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let name = path.file_name().ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "expected a file name, found a folder",
        )
    })?;
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent)?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    // Unique per process and call: two threads (or two processes) writing the same file
    // each rename a whole file of their own.
    static CALLS: AtomicU64 = AtomicU64::new(0);
    tmp_name.push(format!(
        ".tmp{}-{}",
        std::process::id(),
        CALLS.fetch_add(1, Ordering::Relaxed)
    ));
    let tmp = parent.join(tmp_name);
    let written = (|| {
        let mut f = std::io::BufWriter::with_capacity(1 << 16, std::fs::File::create(&tmp)?);
        write(&mut f)?;
        let f = f.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        // Best effort: the temporary file may not exist.
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_whole_files_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("sub/a.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two, longer").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two, longer");
        let names: Vec<_> = std::fs::read_dir(p.parent().unwrap()).unwrap().collect();
        assert_eq!(names.len(), 1);
        // A folder is not a file name.
        assert!(write_atomic(dir.path(), b"x").is_err());
    }

    #[test]
    fn bounded_reads_stop_at_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.toml");
        std::fs::write(&p, "x = 1\n").unwrap();
        assert_eq!(read_text_bounded(&p, 6).unwrap(), "x = 1\n");
        let e = read_text_bounded(&p, 5).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::FileTooLarge);
        assert!(e.to_string().contains("larger than 5 bytes"), "{e}");
        // An endless file: read up to the limit, never more.
        let e = read_bounded(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert!(e.to_string().contains("larger than 1 MiB"), "{e}");
        let e = read_text_bounded(dir.path(), 100).unwrap_err();
        assert!(e.to_string().contains("found a folder"), "{e}");
        // Streamed inputs: regular files up to the limit only.
        check_input_file(&p, 6).unwrap();
        let e = check_input_file(&p, 5).unwrap_err();
        assert!(e.to_string().contains("larger than 5 bytes"), "{e}");
        for odd in [Path::new("/dev/zero"), dir.path()] {
            let e = check_input_file(odd, 1 << 30).unwrap_err();
            assert!(e.to_string().contains("expected a regular file"), "{e}");
        }
        std::fs::write(&p, b"ok\xff").unwrap();
        let e = read_text_bounded(&p, 100).unwrap_err();
        assert!(e.to_string().contains("offset 2"), "{e}");
    }
}
