//! What the machine has: free disk space and available memory, checked
//! before work that would need more, so that a size that cannot be served
//! is refused at once with what it needs and what there is, not after
//! minutes of writing or by the kernel's out-of-memory killer.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Result;

pub use crate::error::Shortage;

/// Bytes an unprivileged process may still write on the file system that
/// holds `dir` (`statvfs`), or `None` where it cannot be told.
pub(crate) fn free_disk(dir: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    let mut st = std::mem::MaybeUninit::<libc::statvfs>::uninit();
    // SAFETY: a NUL-terminated path and a buffer statvfs fills on success.
    if unsafe { libc::statvfs(c.as_ptr(), st.as_mut_ptr()) } != 0 {
        return None;
    }
    // SAFETY: statvfs returned 0, so it filled the buffer.
    let st = unsafe { st.assume_init() };
    // The fields' widths differ between platforms (u64 here).
    #[allow(clippy::useless_conversion)]
    Some(u64::from(st.f_bavail).saturating_mul(u64::from(st.f_frsize)))
}

/// Memory the kernel says it can give without swapping (`MemAvailable`),
/// or `None` where it does not say.
pub(crate) fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib << 10)
}

/// The process's peak resident memory so far, bytes, or `None` where it
/// cannot be told: Linux's `VmHWM`, else `getrusage`. Not `getrusage`
/// first: a process started by `posix_spawn` or `vfork` (Rust's `Command`,
/// Python's `subprocess`) inherits its parent's peak in `ru_maxrss`, since
/// the kernel folds the shared address space's peak into the child's at
/// `execve`; a bake spawned by a 370 MiB test process reported 368 MiB
/// against its own 53.
pub(crate) fn peak_memory() -> Option<u64> {
    if let Ok(status) = std::fs::read_to_string("/proc/self/status") {
        let kib = status
            .lines()
            .find_map(|l| l.strip_prefix("VmHWM:"))
            .and_then(|v| v.split_whitespace().next()?.parse::<u64>().ok());
        if let Some(kib) = kib {
            return Some(kib << 10);
        }
    }
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::uninit();
    // SAFETY: a buffer getrusage fills on success.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, usage.as_mut_ptr()) } != 0 {
        return None;
    }
    // SAFETY: getrusage returned 0, so it filled the buffer.
    let usage = unsafe { usage.assume_init() };
    // Kilobytes on Linux; the field's width differs between platforms.
    #[allow(clippy::useless_conversion)]
    Some(u64::try_from(i64::from(usage.ru_maxrss)).ok()? << 10)
}

/// Whether this process is the `terrabake` command, whose allocator's
/// settings are its own to change; a library's host (Python) keeps its.
static OWNS_ALLOCATOR: AtomicBool = AtomicBool::new(false);

/// Called by the `terrabake` command at its start: [`release_freed_memory`]
/// may then also change how the allocator maps large blocks.
pub fn own_the_allocator() {
    OWNS_ALLOCATOR.store(true, Ordering::Relaxed);
}

/// Gives the heap the process has freed back to the kernel and, in the
/// `terrabake` command ([`own_the_allocator`]), maps every later allocation
/// over 128 KiB on its own, returned whole when freed. A planned bake calls
/// it between the plan and the stages: glibc keeps freed heap, and after
/// freeing the pilot's large buffers it raises its threshold for mapping
/// an allocation (up to 32 MiB), so the stages' buffers then land on heap
/// pages that a free does not give back. The bake peaked at the pilot's
/// residue plus the stages': 206-211 MiB against the 147 of the same stage
/// alone and the 150 planned (UTM tile, 30 directions under
/// `horizon_max`); 168 with the heap given back, 133 with the threshold
/// fixed too. Neither is done on other C libraries.
pub(crate) fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: both only adjust glibc's allocator; no pointer is passed.
    unsafe {
        libc::malloc_trim(0);
        if OWNS_ALLOCATOR.load(Ordering::Relaxed) {
            libc::mallopt(libc::M_MMAP_THRESHOLD, 128 << 10);
        }
    }
}

/// Refuses to write `bytes` to `path` (`what` it is) when the file system
/// has less free.
pub(crate) fn ensure_disk(path: &Path, bytes: u64, what: &str) -> Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    // The directory may not exist yet: ask its nearest existing ancestor.
    let existing = dir
        .ancestors()
        .find(|d| d.exists())
        .unwrap_or(Path::new("."));
    if let Some(free) = free_disk(existing) {
        if bytes > free {
            return Err(Shortage {
                what: format!("{}: {what}", path.display()),
                resource: "disk",
                needed: bytes,
                available: free,
                place: Some(existing.to_path_buf()),
            }
            .into());
        }
    }
    Ok(())
}

/// Refuses work that would hold `bytes` in memory (`what` it is) when the
/// machine has less available.
pub fn ensure_memory(bytes: u64, what: &str) -> crate::Result<()> {
    if let Some(available) = available_memory() {
        if bytes > available {
            return Err(Shortage {
                what: what.to_string(),
                resource: "memory",
                needed: bytes,
                available,
                place: None,
            }
            .into());
        }
    }
    Ok(())
}

/// `n` bytes in binary units, one decimal: "1.5 GiB".
pub(crate) fn human_bytes(n: u64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = n as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < units.len() {
        v /= 1024.0;
        u += 1;
    }
    format!("{v:.1} {}", units[u])
}

#[cfg(test)]
mod tests {
    #[test]
    fn this_machine_has_some_disk_and_memory() {
        assert!(super::free_disk(std::path::Path::new("/")).is_some_and(|b| b > 0));
        assert!(super::available_memory().is_some_and(|b| b > 0));
        assert!(super::ensure_memory(u64::MAX, "everything").is_err());
        assert!(super::ensure_disk(std::path::Path::new("/tmp/x"), u64::MAX, "all").is_err());
        assert!(
            super::ensure_disk(std::path::Path::new("/tmp/no/such/dir/x"), 1, "a byte").is_ok()
        );
    }
}
