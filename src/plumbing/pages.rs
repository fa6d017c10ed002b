//! Large working arrays on huge pages.
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
}
