//! The file-system rules every reader and writer of an asset follows, in one
//! place, so that no caller can forget one:
//!
//! - **Reading** ([`open_regular`], [`read_regular`]): names are checked before anything is
//!   opened ([`check_file_name`]); files are opened without following a
//!   symbolic link (`O_NOFOLLOW`) and without blocking (`O_NONBLOCK`, so a
//!   FIFO planted under a layer's name cannot hang `info` or a renderer), and
//!   anything that is not a regular file is refused before it is read.
//! - **Writing** ([`create_temp`]): a temporary file gets a name no other
//!   writer uses (process id, a counter and the clock) and is created
//!   exclusively (`O_CREAT | O_EXCL`, which never follows a link), so a
//!   link planted at a predictable `.tmp` name is never written through and
//!   a stale temporary never blocks the next run. Renaming it over the
//!   target replaces a link there instead of writing through it.
//! - **Crash points** ([`crash_point`]): every durable step of a writer
//!   (create, write, fsync, rename, unlink) passes one. When the
//!   environment variable `TERRABAKE_CRASH_AT=N` is set, the process aborts
//!   at the N-th step, which is how the kill-at-every-write test reaches
//!   every point where a real crash could land. `TERRABAKE_PANIC_AT=N`
//!   panics there instead, which is how the tests reach the code that
//!   turns a bug's panic into an error (the Python boundary). Unset, a
//!   crash point costs one relaxed atomic increment.

use std::fs::{File, OpenOptions};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{SystemTime, UNIX_EPOCH};

use crate::error::{Error, Location, Result};

/// Suffix of every temporary file a writer creates.
pub const TEMP_SUFFIX: &str = ".tmp";

/// Whether `name` can name a file inside an asset directory: one path
/// component of letters, digits, `_`, `-` and `.`, not starting with a dot,
/// at most 255 bytes. Checked before any file is opened, so a manifest can
/// never make a reader open `../elsewhere` or `/etc/passwd`.
pub fn check_file_name(name: &str) -> std::result::Result<(), String> {
    let ok = !name.is_empty()
        && name.len() <= 255
        && !name.starts_with('.')
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'));
    if ok {
        Ok(())
    } else {
        Err(format!(
            "file name {name:?} is not a plain file name inside the asset (letters, digits, '_', '-', '.'; no leading dot)"
        ))
    }
}

/// Whether `name` is a layer file name as [`crate::LayerWriter`] gives
/// them: `NAME.L<level>.g<generation>.tbl`, NAME of letters, digits, `_`
/// and `-`. A user's `lineitem.tbl` is not one.
pub fn is_layer_file_name(name: &str) -> bool {
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    let Some(rest) = name.strip_suffix(".tbl") else {
        return false;
    };
    let mut parts = rest.rsplitn(3, '.');
    let (Some(generation), Some(level), Some(layer)) = (parts.next(), parts.next(), parts.next())
    else {
        return false;
    };
    generation.strip_prefix('g').is_some_and(digits)
        && level.strip_prefix('L').is_some_and(digits)
        && !layer.is_empty()
        && layer
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

/// The file a temporary made by [`create_temp`] was to become, when `name`
/// is such a temporary (`TARGET.<pid>-<counter>-<hex clock>.tmp`); `None`
/// for any other name, a user's `notes.tmp` among them.
pub fn temporary_target(name: &str) -> Option<&str> {
    let rest = name.strip_suffix(TEMP_SUFFIX)?;
    let (target, unique) = rest.rsplit_once('.')?;
    let mut fields = unique.splitn(3, '-');
    let (pid, counter, clock) = (fields.next()?, fields.next()?, fields.next()?);
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    let hex = clock.len() >= 8 && clock.bytes().all(|b| b.is_ascii_hexdigit());
    (digits(pid) && digits(counter) && hex && !target.is_empty()).then_some(target)
}

/// Whether `name` is a file that an asset's writer makes and may reclaim:
/// a layer file, or a temporary of a layer file or of the manifest. The
/// manifest and the lock are the asset's own, never reclaimed, and not
/// counted here. Nothing else in an asset directory is ever removed.
pub fn is_reclaimable_name(name: &str) -> bool {
    is_layer_file_name(name)
        || temporary_target(name)
            .is_some_and(|t| t == crate::MANIFEST_FILE || is_layer_file_name(t))
}

/// Opens `path` for reading: no link followed, no blocking on a FIFO or
/// device, and an error unless it is a regular file.
pub fn open_regular(path: &Path) -> Result<File> {
    let io = |source| Error::Io {
        at: Location::file(path),
        source,
    };
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_CLOEXEC)
        .open(path)
        .map_err(|e| {
            // ELOOP is how O_NOFOLLOW reports a link: say so plainly.
            if e.raw_os_error() == Some(libc::ELOOP) {
                Error::malformed(
                    Location::file(path),
                    "is a symbolic link; asset files are never read through links",
                )
            } else {
                io(e)
            }
        })?;
    let meta = file.metadata().map_err(io)?;
    if !meta.file_type().is_file() {
        return Err(Error::malformed(
            Location::file(path),
            "is not a regular file (a directory, FIFO, socket or device)",
        ));
    }
    Ok(file)
}

/// The regular file `path` whole, or its first `limit` bytes where it is
/// longer, opened as [`open_regular`] opens it: a caller that refuses a
/// file past some size passes one byte more and checks the length.
pub fn read_regular(path: &Path, limit: u64) -> Result<Vec<u8>> {
    use std::io::Read;
    let mut bytes = Vec::new();
    open_regular(path)?
        .take(limit)
        .read_to_end(&mut bytes)
        .map_err(|source| Error::Io {
            at: Location::file(path),
            source,
        })?;
    Ok(bytes)
}

/// A fresh temporary file beside `target` (same directory, so the final
/// rename is atomic), created exclusively under a unique name. Returns the
/// file and its path.
pub fn create_temp(target: &Path) -> std::io::Result<(File, PathBuf)> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let dir = target.parent().unwrap_or(Path::new("."));
    let base = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    loop {
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let path = dir.join(format!(
            "{base}.{}-{n}-{nanos:08x}{TEMP_SUFFIX}",
            std::process::id()
        ));
        crash_point();
        // Created and registered under the one lock: an interrupt between
        // the two would leave a temporary it never knew of, and one after
        // it has taken the list must find no new one made.
        let mut registered = TEMPORARIES.lock().unwrap_or_else(|e| e.into_inner());
        if INTERRUPTED.load(Ordering::SeqCst) {
            return Err(std::io::Error::new(
                std::io::ErrorKind::Interrupted,
                "interrupted: no new temporary file",
            ));
        }
        match OpenOptions::new()
            .write(true)
            .create_new(true)
            .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
            .mode(0o644)
            .open(&path)
        {
            Ok(file) => {
                registered.push(path.clone());
                return Ok((file, path));
            }
            // Someone (or something) holds that name: take another.
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
}

/// Every temporary this process has created (a name is never used twice,
/// so one renamed into place or removed since is simply gone).
static TEMPORARIES: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());
/// Set once [`remove_temporaries`] has run: the process is ending, and
/// [`create_temp`] makes no more.
static INTERRUPTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Removes every temporary this process created that is still there, and
/// returns how many: for a writer interrupted (Ctrl-C, a scheduler's
/// SIGTERM) before it could clean up, so that it leaves nothing half
/// written behind. Committed files are never touched, and no temporary is
/// created after it.
pub fn remove_temporaries() -> usize {
    let mut registered = TEMPORARIES.lock().unwrap_or_else(|e| e.into_inner());
    INTERRUPTED.store(true, Ordering::SeqCst);
    let paths = std::mem::take(&mut *registered);
    drop(registered);
    paths
        .iter()
        .filter(|p| std::fs::remove_file(p).is_ok())
        .count()
}

/// Fsyncs the directory `dir`, so that renames and unlinks in it are durable.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    crash_point();
    File::open(dir)?.sync_all()
}

/// Asks the kernel to start writing `len` bytes of `file` from `offset` to
/// the disk, without waiting (Linux's `sync_file_range`; elsewhere
/// nothing), so that the fsync which makes a file durable waits for its
/// last stretch, not for all of it at the end of a stage. Advisory: an
/// error here is one that fsync reports.
pub fn start_writeback(file: &File, offset: u64, len: u64) {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        let (offset, len) = (offset as libc::off64_t, len as libc::off64_t);
        // SAFETY: a system call on an open descriptor that reads no memory.
        unsafe {
            libc::sync_file_range(file.as_raw_fd(), offset, len, libc::SYNC_FILE_RANGE_WRITE)
        };
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (file, offset, len);
}

/// One durable step of a writer; see the module docs.
#[inline]
pub fn crash_point() {
    static AT: OnceLock<(Option<u64>, Option<u64>)> = OnceLock::new();
    static STEPS: AtomicU64 = AtomicU64::new(0);
    let step = |name: &str| std::env::var(name).ok().and_then(|v| v.parse().ok());
    let (crash, panic) =
        *AT.get_or_init(|| (step("TERRABAKE_CRASH_AT"), step("TERRABAKE_PANIC_AT")));
    if crash.is_some() || panic.is_some() {
        let n = STEPS.fetch_add(1, Ordering::Relaxed) + 1;
        if crash == Some(n) {
            // As a kill would: no unwinding, no destructors, no cleanup.
            std::process::abort();
        }
        if panic == Some(n) {
            panic!("TERRABAKE_PANIC_AT={n}: a panic injected at a durable step");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_that_leave_the_asset_are_refused() {
        for bad in [
            "",
            "../x.tbl",
            "/etc/passwd",
            ".hidden",
            "a/b",
            "a\\b",
            "x\0y",
            "é.tbl",
        ] {
            assert!(check_file_name(bad).is_err(), "{bad:?}");
        }
        for good in ["height.L0.g0.tbl", "manifest.tba", "a-b_c.L12.g3.tbl"] {
            assert!(check_file_name(good).is_ok(), "{good:?}");
        }
    }

    #[test]
    fn only_the_writers_own_names_are_reclaimable() {
        for ours in [
            "height.L0.g0.tbl",
            "pyramid_max-x.L12.g345.tbl",
            "height.L0.g7.tbl.4242-3-0badc0de.tmp",
            "manifest.tba.17-0-12345678.tmp",
        ] {
            assert!(is_reclaimable_name(ours), "{ours:?}");
        }
        for theirs in [
            "lineitem.tbl",
            "notes.tmp",
            "orders.L0.tbl",
            "x.Lz.g0.tbl",
            "x.L0.g.tbl",
            ".L0.g0.tbl",
            "a b.L0.g0.tbl",
            "report.txt.tmp",
            "lineitem.tbl.1-2-3.tmp",
            "height.L0.g0.tbl.12-x-0badc0de.tmp",
            "data.1-2-0badc0de.tmp",
            "manifest.tba",
            "writer.lock",
        ] {
            assert!(!is_reclaimable_name(theirs), "{theirs:?}");
        }
        // What create_temp makes is recognised as its target's temporary.
        let dir = tempfile::tempdir().unwrap();
        let (_f, p) = create_temp(&dir.path().join("height.L0.g2.tbl")).unwrap();
        let name = p.file_name().unwrap().to_str().unwrap();
        assert_eq!(temporary_target(name), Some("height.L0.g2.tbl"));
        assert!(is_reclaimable_name(name));
    }

    #[test]
    fn temporaries_are_unique_and_never_written_through_links() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.tif");
        let victim = dir.path().join("victim");
        std::fs::write(&victim, b"precious").unwrap();
        // A link at every name a naive writer would use.
        std::os::unix::fs::symlink(&victim, dir.path().join("out.tif.tmp")).unwrap();
        let (mut a, pa) = create_temp(&target).unwrap();
        let (_b, pb) = create_temp(&target).unwrap();
        assert_ne!(pa, pb);
        use std::io::Write;
        a.write_all(b"new").unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
        let name = pa.file_name().unwrap().to_str().unwrap();
        assert!(
            name.starts_with("out.tif.") && name.ends_with(TEMP_SUFFIX),
            "{name}"
        );
    }

    #[test]
    fn open_regular_refuses_links_fifos_and_directories() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("f");
        std::fs::write(&file, b"x").unwrap();
        assert!(open_regular(&file).is_ok());
        let link = dir.path().join("l");
        std::os::unix::fs::symlink(&file, &link).unwrap();
        let e = open_regular(&link).unwrap_err().to_string();
        assert!(e.contains("symbolic link"), "{e}");
        assert!(open_regular(dir.path())
            .unwrap_err()
            .to_string()
            .contains("not a regular file"));
        let fifo = dir.path().join("fifo");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
        // Returns at once (O_NONBLOCK) and refuses it.
        assert!(open_regular(&fifo)
            .unwrap_err()
            .to_string()
            .contains("not a regular file"));
    }
}
