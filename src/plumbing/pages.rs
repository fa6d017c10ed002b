//! Large working arrays on huge pages, and mapped pages already read given
//! back ([`release_file_pages`]).
//!
//! The algorithms that read a grid at scattered places rather than along
//! its rows (the cone planes' open-cell scan reads the blocks of a row
//! whose cells can open, and each of a cell's apex slice, slope and floor
//! lies in an array of its own) touch a new 4 KiB page on nearly every
//! access, so their time goes to TLB misses as much as to memory.
//! Linux backs an anonymous mapping with 2 MiB pages when it is advised to
//! (`MADV_HUGEPAGE`), and where transparent huge pages are set to
//! `madvise`, as on this project's machines, only then. The advice
//! is given before the first touch, so that the first faults already take
//! huge pages. It is only advice: where the kernel has none to give, or on
//! another system, the arrays are ordinary ones and the results the same.

/// Below this an array gains nothing: it spans fewer pages than the TLB
/// holds.
const WORTH_ADVISING: usize = 8 << 20;

/// An empty vector with room for `len` values, its memory advised onto
/// huge pages where it is large enough to gain: fill it in place (`resize`,
/// or rayon's `par_extend` to write it once, in parallel).
pub fn with_capacity<T>(len: usize) -> Vec<T> {
    let mut v: Vec<T> = Vec::with_capacity(len);
    advise_huge(v.as_mut_ptr().cast(), len * std::mem::size_of::<T>());
    v
}

/// A vector of `len` copies of `value`, on huge pages as [`with_capacity`].
pub fn filled<T: Clone>(len: usize, value: T) -> Vec<T> {
    let mut v = with_capacity(len);
    v.resize(len, value);
    v
}

fn advise_huge(start: *mut u8, bytes: usize) {
    #[cfg(target_os = "linux")]
    if bytes >= WORTH_ADVISING {
        const PAGE: usize = 4096;
        let first = (start as usize).next_multiple_of(PAGE);
        let end = (start as usize + bytes) & !(PAGE - 1);
        // SAFETY: the range lies within the allocation behind `start`, on
        // page boundaries; madvise with MADV_HUGEPAGE changes how the pages
        // are backed, never their contents. Its result is only advice
        // taken or not.
        unsafe {
            libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_HUGEPAGE);
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (start, bytes);
}

/// Lets the kernel take back the resident pages wholly inside `span`, a
/// part of a file mapped read-only that has been read: they stay in the
/// page cache, and a later read maps them again. A stage that reads a
/// mapped layer once, in order, calls it behind itself, so that its
/// resident memory (which a planned bake's peak counts) grows with what it
/// holds, not with the layer. Only advice where the kernel keeps no such
/// pages; a no-op off Linux.
///
/// # Safety
///
/// `span` must lie in a read-only mapping of a file (never heap or an
/// anonymous mapping, whose pages the advice would zero).
pub unsafe fn release_file_pages(span: &[u8]) {
    #[cfg(target_os = "linux")]
    {
        const PAGE: usize = 4096;
        let first = (span.as_ptr() as usize).next_multiple_of(PAGE);
        let end = (span.as_ptr() as usize + span.len()) & !(PAGE - 1);
        if end > first {
            // SAFETY: whole pages inside `span`, which the caller vouches
            // is a read-only file mapping: dropping them loses nothing.
            unsafe {
                libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_DONTNEED);
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = span;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Small and large, the vector holds what it was asked to, filled
    /// whole or extended in parallel in place.
    #[test]
    fn advised_vectors_hold_their_values() {
        use rayon::prelude::*;
        for len in [0, 1, 4095, (WORTH_ADVISING / 2) + 3] {
            let v = filled(len, 7u16);
            assert_eq!(v.len(), len);
            assert!(v.iter().all(|&x| x == 7));
            let mut w = with_capacity::<u16>(len);
            let at = w.as_ptr();
            w.par_extend((0..len).into_par_iter().map(|i| i as u16));
            assert_eq!(w.len(), len);
            assert!(w.iter().enumerate().all(|(i, &x)| x == i as u16));
            // Written into the advised memory, not a reallocation.
            assert_eq!(w.as_ptr(), at);
        }
    }

    /// Resident KiB of the mapping that starts at `start`, as the kernel
    /// counts it for this process (`/proc/self/smaps`): other threads'
    /// allocations do not move it.
    #[cfg(target_os = "linux")]
    fn resident_kib(start: *const u8) -> u64 {
        let smaps = std::fs::read_to_string("/proc/self/smaps").unwrap();
        let head = format!("{:x}-", start as usize);
        let mut lines = smaps.lines().skip_while(|l| !l.starts_with(&head));
        lines
            .find_map(|l| l.strip_prefix("Rss:"))
            .and_then(|v| v.split_whitespace().next()?.parse().ok())
            .expect("the mapping in smaps")
    }

    /// Released pages leave the process's resident memory, and what they
    /// held reads back the same from the file.
    #[cfg(target_os = "linux")]
    #[test]
    fn released_file_pages_leave_residence_and_read_back_the_same() {
        use std::io::Write;
        let bytes: Vec<u8> = (0..16u32 << 20)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8)
            .collect();
        let mut file = tempfile::tempfile().unwrap();
        file.write_all(&bytes).unwrap();
        // SAFETY: a file of this test's own, not changed while mapped.
        let map = unsafe { terrabake_format::Mmap::map(&file) }.unwrap();
        assert!(map[..] == bytes[..]);
        assert!(resident_kib(map.as_ptr()) >= 15 << 10);
        // SAFETY: a read-only file mapping.
        unsafe { release_file_pages(&map[..]) };
        assert!(resident_kib(map.as_ptr()) < 64);
        assert!(map[..] == bytes[..]);
    }
}
