//! The vector code of the sliced planes' two row scans, per instruction
//! set: the open-cell scan ([`crate::algorithms::planes::open_cells`]: which cells of a row a
//! slice can narrow) and the reach test ([`crate::algorithms::planes::keep_in_reach`]: which
//! columns' parabolas can narrow them). Both test eight cells or columns
//! at a time and append the ones that pass, in order, to a list: AVX-512
//! compresses them in a register; AVX2 has no compress, so a permutation
//! looked up by the pass mask ([`COMPRESS`]) stands in for it. Every
//! kernel gives what the scalar code in `planes.rs` gives, bit for bit
//! (the module's tests run each one the CPU has against the definitions);
//! which one runs is [`crate::plumbing::simd::level`].
//!
//! AVX2 matters beside AVX-512: most x86 CPUs in use have AVX2 and no
//! AVX-512, and with the scalar code the 8192², K = 256 bake missed its
//! 30 s target there (docs/BENCHMARKS.md).

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

#[cfg(target_arch = "x86_64")]
use super::scan::{open_block, RowCells, Scan, BLOCK};
use super::{each_awake_block, Kept, Span};

/// For each mask of `MASKS` (2^lanes) lanes, the 32-bit lanes that pack
/// the lanes set to the front of a vector, in order, one byte each (the
/// rest 0), each lane `halves` 32-bit lanes wide: the permutation that
/// stands in for a compress.
#[cfg(target_arch = "x86_64")]
const fn compress_table<const MASKS: usize>(halves: usize) -> [u64; MASKS] {
    let mut table = [0u64; MASKS];
    let mut mask = 0;
    while mask < MASKS {
        let (mut packed, mut to, mut lane) = (0u64, 0, 0);
        while 1 << lane < MASKS {
            if mask >> lane & 1 == 1 {
                let mut half = 0;
                while half < halves {
                    packed |= ((halves * lane + half) as u64) << (8 * to);
                    (to, half) = (to + 1, half + 1);
                }
            }
            lane += 1;
        }
        table[mask] = packed;
        mask += 1;
    }
    table
}

/// Eight 32-bit lanes.
#[cfg(target_arch = "x86_64")]
const COMPRESS: [u64; 256] = compress_table(1);

/// Four 64-bit lanes, each as its two 32-bit halves.
#[cfg(target_arch = "x86_64")]
const COMPRESS_PAIRS: [u64; 16] = compress_table(2);

/// The eight columns (or cells) from `c0` on, one to a 32-bit lane.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
fn columns(c0: u32) -> __m256i {
    _mm256_add_epi32(
        _mm256_set1_epi32(c0 as i32),
        _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
    )
}

/// The lanes of `v` set in `mask`, packed to the front.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
fn compress_epi32(v: __m256i, mask: u8) -> __m256i {
    let index = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(COMPRESS[usize::from(mask)] as i64));
    _mm256_permutevar8x32_epi32(v, index)
}

/// The lanes of `v` set in `mask` (four bits), packed to the front.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
fn compress_pd(v: __m256d, mask: u8) -> __m256d {
    let index = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(
        COMPRESS_PAIRS[usize::from(mask & 15)] as i64,
    ));
    _mm256_castsi256_pd(_mm256_permutevar8x32_epi32(_mm256_castpd_si256(v), index))
}

/// The two halves of eight 32-bit integers as `f64`.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
fn halves_pd(v: __m256i) -> [__m256d; 2] {
    [
        _mm256_cvtepi32_pd(_mm256_castsi256_si128(v)),
        _mm256_cvtepi32_pd(_mm256_extracti128_si256::<1>(v)),
    ]
}

/// Eight `f64` compare masks (two halves) as the bits of one byte.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
fn mask_bits([lo, hi]: [__m256d; 2]) -> u8 {
    (_mm256_movemask_pd(lo) | _mm256_movemask_pd(hi) << 4) as u8
}

/// [`crate::algorithms::planes::open_cells`] eight cells at a time in AVX2; a last block of
/// fewer cells one at a time. Returns the count, the reach and the blocks
/// read.
///
/// # Safety
/// AVX2 and popcnt; `targets` at least the row and a vector long, `wakes`
/// one per block of the row, every member an index of `scan.rise_of`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
pub(super) unsafe fn open_cells_avx2(
    cells: RowCells,
    scan: Scan,
    wakes: &mut [u16],
    targets: &mut [u32],
) -> (usize, f64, u64) {
    const _: () = assert!(BLOCK == 8, "a block is one vector");
    let RowCells {
        member,
        slope,
        floor,
    } = cells;
    let len = member.len();
    assert!(targets.len() >= len + 8);
    let unit = _mm256_set1_pd(scan.unit);
    let per_count = _mm256_set1_pd(scan.slices_per_count);
    let never = _mm256_set1_pd(f64::from(u16::MAX));
    let (one, most) = (_mm256_set1_epi32(1), _mm256_set1_epi32(i32::from(u16::MAX)));
    let mut n = 0;
    let mut widest = [_mm256_setzero_pd(); 2];
    let mut widest_tail = [0.0f64; 8];
    let blocks_read = each_awake_block(wakes, scan.slice, cells, |b| {
        let c0 = b * BLOCK;
        if len - c0 < BLOCK {
            return open_block(b, cells, scan, targets, &mut n, &mut widest_tail);
        }
        // SAFETY: `c0 + 8 <= len`.
        let (m, s, f) = unsafe {
            (
                _mm256_cvtepu16_epi32(_mm_loadu_si128(member.as_ptr().add(c0).cast())),
                _mm256_loadu_ps(slope.as_ptr().add(c0)),
                _mm256_cvtepu16_epi32(_mm_loadu_si128(floor.as_ptr().add(c0).cast())),
            )
        };
        let s = [
            _mm256_cvtps_pd(_mm256_castps256_ps128(s)),
            _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(s)),
        ];
        let f = halves_pd(f);
        let halves = [_mm256_castsi256_si128(m), _mm256_extracti128_si256::<1>(m)];
        // SAFETY: members index `rise_of`.
        let rise = halves.map(|m| unsafe { _mm256_i32gather_pd::<8>(scan.rise_of.as_ptr(), m) });
        let v = [0, 1].map(|h| _mm256_mul_pd(s[h], rise[h]));
        // (inf * 0 is NaN, which is never greater.)
        let open = [0, 1].map(|h| _mm256_cmp_pd::<_CMP_GT_OQ>(v[h], _mm256_mul_pd(f[h], unit)));
        let bits = mask_bits(open);
        if bits != 0 {
            // Stored whole (the lanes past the open ones are overwritten
            // or truncated later), and only where a lane is open, as in
            // `open_cells_avx512`. SAFETY: `n + 8 <= targets.len()`.
            unsafe {
                let index = columns(c0 as u32);
                _mm256_storeu_si256(
                    targets.as_mut_ptr().add(n).cast(),
                    compress_epi32(index, bits),
                );
            }
            n += bits.count_ones() as usize;
            for h in 0..2 {
                let wider = _mm256_max_pd(widest[h], v[h]);
                widest[h] = _mm256_blendv_pd(widest[h], wider, open[h]);
            }
            return 0;
        }
        // The wakes, as `Scan::wake`, with its division: the same wakes.
        let x = [0, 1].map(|h| {
            let x = _mm256_div_pd(_mm256_mul_pd(f[h], per_count), s[h]);
            // (A NaN, 0 / 0, takes the second operand: never.)
            _mm256_cvttpd_epi32(_mm256_min_pd(x, never))
        });
        let x = _mm256_set_m128i(x[1], x[0]);
        let w = _mm256_add_epi32(
            m,
            _mm256_max_epi32(_mm256_sub_epi32(x, one), _mm256_setzero_si256()),
        );
        let w = _mm256_min_epi32(w, most);
        // SAFETY: eight i32 lanes as an array.
        let w: [i32; 8] = unsafe { std::mem::transmute(w) };
        w.into_iter().min().unwrap_or(0) as u16
    });
    let mut lanes = [0.0f64; 8];
    // SAFETY: four f64 lanes each, into 8.
    unsafe {
        _mm256_storeu_pd(lanes.as_mut_ptr(), widest[0]);
        _mm256_storeu_pd(lanes.as_mut_ptr().add(4), widest[1]);
    }
    let reach = lanes.into_iter().chain(widest_tail).fold(0.0, f64::max);
    (n, reach, blocks_read)
}

/// [`crate::algorithms::planes::open_cells`] eight cells at a time; returns the count, the reach and
/// the blocks read.
///
/// # Safety
/// AVX-512 F, VL and BW; `targets` at least the row and a vector long,
/// `wakes` one per block of the row, every member an index of
/// `scan.rise_of`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512bw,popcnt")]
pub(super) unsafe fn open_cells_avx512(
    cells: RowCells,
    scan: Scan,
    wakes: &mut [u16],
    targets: &mut [u32],
) -> (usize, f64, u64) {
    const _: () = assert!(BLOCK == 8, "a block is one vector");
    let RowCells {
        member,
        slope,
        floor,
    } = cells;
    let len = member.len();
    let unit = _mm512_set1_pd(scan.unit);
    let per_count = _mm512_set1_pd(scan.slices_per_count);
    let never = _mm512_set1_pd(f64::from(u16::MAX));
    assert!(targets.len() >= len + 8);
    let mut n = 0;
    let mut widest = _mm512_setzero_pd();
    let zero = _mm512_setzero_pd();
    let (one, most) = (_mm256_set1_epi32(1), _mm256_set1_epi32(i32::from(u16::MAX)));
    let blocks_read = each_awake_block(wakes, scan.slice, cells, |b| {
        let c0 = b * BLOCK;
        let lanes: __mmask8 = if len - c0 >= 8 {
            0xff
        } else {
            (1u8 << (len - c0)) - 1
        };
        // SAFETY: lanes past the row are masked; members index `rise_of`.
        let (m, s, f) = unsafe {
            (
                _mm256_cvtepu16_epi32(_mm_maskz_loadu_epi16(lanes, member.as_ptr().add(c0).cast())),
                _mm512_cvtps_pd(_mm256_maskz_loadu_ps(lanes, slope.as_ptr().add(c0))),
                _mm512_cvtepi32_pd(_mm256_cvtepu16_epi32(_mm_maskz_loadu_epi16(
                    lanes,
                    floor.as_ptr().add(c0).cast(),
                ))),
            )
        };
        // SAFETY: as above.
        let rise = unsafe { _mm512_mask_i32gather_pd::<8>(zero, lanes, m, scan.rise_of.as_ptr()) };
        let v = _mm512_mul_pd(s, rise);
        // (inf * 0 is NaN, which is never greater.)
        let open = _mm512_mask_cmp_pd_mask::<_CMP_GT_OQ>(lanes, v, _mm512_mul_pd(f, unit));
        if open != 0 {
            // Compressed in a register and stored whole (the lanes past the
            // open ones are overwritten or truncated later): the compressing
            // store to memory is microcoded on AMD's Zen 4, and took 45 % of
            // the bake there. Only where a lane is open: a block with none
            // would store at the same unaligned place as the last, split
            // across cache lines. SAFETY: `n + 8 <= targets.len()`.
            unsafe {
                let index = columns(c0 as u32);
                _mm256_storeu_si256(
                    targets.as_mut_ptr().add(n).cast(),
                    _mm256_maskz_compress_epi32(open, index),
                )
            };
            n += open.count_ones() as usize;
            widest = _mm512_mask_max_pd(widest, open, widest, v);
            0
        } else {
            // The wakes, as `Scan::wake` (the reciprocal within 2^-14,
            // below the margin); lanes past the row never wake.
            let x = _mm512_mul_pd(_mm512_mul_pd(f, per_count), _mm512_rcp14_pd(s));
            // (A NaN, 0 / 0, takes the second operand: never.)
            let x = _mm512_cvttpd_epi32(_mm512_min_pd(x, never));
            let w = _mm256_add_epi32(
                m,
                _mm256_max_epi32(_mm256_sub_epi32(x, one), _mm256_setzero_si256()),
            );
            let w = _mm256_mask_blend_epi32(lanes, most, _mm256_min_epi32(w, most));
            // SAFETY: eight i32 lanes as an array.
            let w: [i32; 8] = unsafe { std::mem::transmute(w) };
            w.into_iter().min().unwrap_or(0) as u16
        }
    });
    (n, _mm512_reduce_max_pd(widest), blocks_read)
}

/// [`crate::algorithms::planes::keep_in_reach`] eight columns at a time in AVX2; the columns
/// past the last whole vector one at a time.
///
/// # Safety
/// AVX2 and popcnt; `kept` with room for `n + g.len() + 8`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
pub(super) unsafe fn keep_in_reach_avx2(
    g: &[u16],
    c0: u32,
    test: Span,
    kept: &mut Kept,
    mut n: usize,
) -> usize {
    let whole = g.len() / 8 * 8;
    assert!(kept.columns.len() >= n + whole + 8 && kept.offsets.len() >= n + whole + 8);
    let (aspect, reach2) = (_mm256_set1_pd(test.aspect), _mm256_set1_pd(test.reach2));
    let none = _mm256_set1_epi32(i32::from(u16::MAX));
    let (first, last) = (
        _mm256_set1_epi32(test.first as i32),
        _mm256_set1_epi32(test.last as i32),
    );
    // `Span::hidden_bits` from the plane cells and those within the offset
    // of 1, eight columns a compare, the rest one at a time.
    let near_v = _mm_set1_epi16(test.hidden as i16);
    let bits = |m: __m128i| _mm_movemask_epi8(_mm_packs_epi16(m, _mm_setzero_si128())) as u64;
    let (mut plane, mut near) = test.plane_and_near(g, whole);
    for j in (0..whole).step_by(8) {
        // SAFETY: `j + 8 <= g.len()`.
        let here = unsafe { _mm_loadu_si128(g.as_ptr().add(j).cast()) };
        plane |= bits(_mm_cmpeq_epi16(here, _mm_setzero_si128())) << j;
        near |= bits(_mm_cmpeq_epi16(_mm_min_epu16(here, near_v), here)) << j;
    }
    let hidden = Span::hidden_bits(plane, near);
    let mut index = columns(c0);
    for j in (0..whole).step_by(8) {
        // SAFETY: `j + 8 <= g.len()`.
        let gi = _mm256_cvtepu16_epi32(unsafe { _mm_loadu_si128(g.as_ptr().add(j).cast()) });
        let along = _mm256_max_epi32(
            _mm256_max_epi32(
                _mm256_sub_epi32(first, index),
                _mm256_sub_epi32(index, last),
            ),
            _mm256_setzero_si256(),
        );
        // The scalar code's operations in its order: the same bits.
        let gd = halves_pd(gi).map(|g| _mm256_mul_pd(g, aspect));
        let offset = gd.map(|g| _mm256_mul_pd(g, g));
        let along = halves_pd(along);
        let near = mask_bits([0, 1].map(|h| {
            let d2 = _mm256_add_pd(offset[h], _mm256_mul_pd(along[h], along[h]));
            _mm256_cmp_pd::<_CMP_LT_OQ>(d2, reach2)
        }));
        let some = !_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(gi, none))) as u8;
        let keep = near & some & !(hidden >> j) as u8;
        let low = (keep & 15).count_ones() as usize;
        // Stored whole, and only where a lane is kept, as in
        // `keep_in_reach_avx512`.
        if keep != 0 {
            // SAFETY: `n + 8` within both.
            unsafe {
                _mm256_storeu_si256(
                    kept.columns.as_mut_ptr().add(n).cast(),
                    compress_epi32(index, keep),
                );
                _mm256_storeu_pd(
                    kept.offsets.as_mut_ptr().add(n),
                    compress_pd(offset[0], keep),
                );
                _mm256_storeu_pd(
                    kept.offsets.as_mut_ptr().add(n + low),
                    compress_pd(offset[1], keep >> 4),
                );
            }
        }
        n += keep.count_ones() as usize;
        index = _mm256_add_epi32(index, _mm256_set1_epi32(8));
    }
    test.keep_scalar(g, whole, hidden, c0, kept, n)
}

/// [`crate::algorithms::planes::keep_in_reach`] eight columns at a time in AVX-512.
///
/// # Safety
/// AVX-512 F, VL and BW; `kept` with room for `n + g.len() + 8`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512bw,popcnt")]
pub(super) unsafe fn keep_in_reach_avx512(
    g: &[u16],
    c0: u32,
    test: Span,
    kept: &mut Kept,
    mut n: usize,
) -> usize {
    let Span {
        first,
        last,
        aspect,
        reach2,
        ..
    } = test;
    let len = g.len();
    assert!(kept.columns.len() >= n + len + 8 && kept.offsets.len() >= n + len + 8);
    // `Span::hidden_bits` for every column, from the plane cells and
    // those within the offset of 1, eight columns a compare.
    let near_v = _mm_set1_epi16(test.hidden as i16);
    let (mut plane, mut near) = (0u64, 0u64);
    for j in (0..len).step_by(8) {
        let lanes = (0xffu32 >> 8u32.saturating_sub((len - j) as u32)) as __mmask8;
        // SAFETY: lanes past the slice are masked.
        let here = unsafe { _mm_maskz_loadu_epi16(lanes, g.as_ptr().add(j).cast()) };
        plane |= u64::from(_mm_mask_cmpeq_epi16_mask(lanes, here, _mm_setzero_si128())) << j;
        near |= u64::from(_mm_mask_cmple_epu16_mask(lanes, here, near_v)) << j;
    }
    let hidden = Span::hidden_bits(plane, near);
    let (aspect, reach2) = (_mm512_set1_pd(aspect), _mm512_set1_pd(reach2));
    let none = _mm256_set1_epi32(i32::from(u16::MAX));
    let (first, last) = (
        _mm256_set1_epi32(first as i32),
        _mm256_set1_epi32(last as i32),
    );
    let mut index = columns(c0);
    for j in (0..len).step_by(8) {
        let lanes: __mmask8 = if len - j >= 8 {
            0xff
        } else {
            (1u8 << (len - j)) - 1
        };
        // SAFETY: lanes past the slice are masked.
        let gi = _mm256_cvtepu16_epi32(unsafe {
            _mm_maskz_loadu_epi16(lanes, g.as_ptr().add(j).cast())
        });
        let along = _mm256_max_epi32(
            _mm256_max_epi32(
                _mm256_sub_epi32(first, index),
                _mm256_sub_epi32(index, last),
            ),
            _mm256_setzero_si256(),
        );
        let gd = _mm512_mul_pd(_mm512_cvtepi32_pd(gi), aspect);
        let offset = _mm512_mul_pd(gd, gd);
        let along = _mm512_cvtepi32_pd(along);
        let d2 = _mm512_add_pd(offset, _mm512_mul_pd(along, along));
        let keep = _mm256_mask_cmpneq_epi32_mask(lanes, gi, none)
            & _mm512_cmp_pd_mask::<_CMP_LT_OQ>(d2, reach2)
            & !(hidden >> j) as u8;
        // Compressed in registers, as in `open_cells_avx512`, and not
        // stored where no lane is kept: runs of hidden plane cells would
        // store at one unaligned place again and again, each store split
        // across cache lines (1.2x slower in all).
        if keep != 0 {
            // SAFETY: `n + 8` within both.
            unsafe {
                _mm256_storeu_si256(
                    kept.columns.as_mut_ptr().add(n).cast(),
                    _mm256_maskz_compress_epi32(keep, index),
                );
                _mm512_storeu_pd(
                    kept.offsets.as_mut_ptr().add(n),
                    _mm512_maskz_compress_pd(keep, offset),
                );
            }
        }
        n += keep.count_ones() as usize;
        index = _mm256_add_epi32(index, _mm256_set1_epi32(8));
    }
    n
}
