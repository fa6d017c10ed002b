//! The shadow kernel: a row of posts through one [`RowDay`], each post's
//! sunlit steps found against its stored horizon and summed by their
//! running sums.
//!
//! A post is sunlit at a step when the sun's centre stands above the
//! horizon at its azimuth, read exactly as the loader serves it
//! ([`terrabake_format::horizons::between`] of the two bands around the
//! azimuth, the edge marker never blended), and in front of the surface
//! (`N . s > 0`). The test runs on sixteen posts at once in `f32`; where
//! the sun stands within 0.001 degrees of a horizon, or within 1e-5 of the
//! surface's plane, the post is decided again in `f64` by [`sunlit`], the
//! definition itself, so that the vector code never decides a post
//! differently from it (the `f32` error is below 3e-5 degrees). Only where
//! a post's state changes does it touch its sums: the running sums at that
//! step, subtracted where its sun comes out and added where it goes in.

use terrabake_format::horizons::between;

use super::{levels_around, RowDay, RowStep, Sums, COMPONENTS, LEVELS};

/// Posts tested together.
const LANES: usize = 16;

/// The sums one post keeps: every weight at every height level.
const KEPT: usize = LEVELS * COMPONENTS;

/// How near (degrees) the sun may stand to a horizon, and (as a cosine)
/// to the surface's plane, before the `f32` test defers to [`sunlit`].
const NEAR_HORIZON: f32 = 1e-3;
const NEAR_PLANE: f32 = 1e-5;

/// Whether a post with unit `normal` and horizon angles `h0`, `h1`
/// (degrees) in the bands around the sun's azimuth sees the sun's centre
/// at `step`: the definition every path of the kernel and the references
/// share.
#[inline]
pub fn sunlit(h0: f32, h1: f32, step: &RowStep, normal: [f64; 3]) -> bool {
    let horizon = between(f64::from(h0), f64::from(h1), step.between);
    let facing = normal[0] * step.sun[0] + normal[1] * step.sun[1] + normal[2] * step.sun[2];
    step.elevation > horizon && facing > 0.0
}

/// Lanes' test at one step, as bit masks: bit `l` of the first is set where
/// lane `l` is sunlit by the `f32` test, of the second where that test is
/// too near to call. One definition ([`masks_portable`]); the AVX2 path
/// ([`masks_avx2`]) computes the same with a vector compare and a
/// move-mask per eight lanes, which the compiler does not find in the
/// portable loop (it gathered the bits one by one: four fifths of the
/// kernel's time). [`ShadowRow::add_day`] picks one per row and day.
trait Masks: Fn(&[f32], &[f32], &RowStep, &[[f32; LANES]; 3]) -> (u32, u32) {}

impl<F: Fn(&[f32], &[f32], &RowStep, &[[f32; LANES]; 3]) -> (u32, u32)> Masks for F {}

/// The `f32` test, lane by lane.
#[inline(always)]
fn masks_portable(
    h0: &[f32],
    h1: &[f32],
    step: &RowStep,
    normal: &[[f32; LANES]; 3],
) -> (u32, u32) {
    let (el, f) = (step.elevation as f32, step.between as f32);
    let s = step.sun.map(|v| v as f32);
    let (mut now, mut near) = (0u32, 0u32);
    for l in 0..LANES {
        let (a, b) = (h0[l], h1[l]);
        // The edge marker is never blended (`between`).
        let a2 = if a == -90.0 { b } else { a };
        let b2 = if b == -90.0 { a } else { b };
        let d = el - (a2 + f * (b2 - a2));
        let facing = normal[0][l] * s[0] + normal[1][l] * s[1] + normal[2][l] * s[2];
        now |= u32::from((d > 0.0) & (facing > 0.0)) << l;
        near |= u32::from((d.abs() < NEAR_HORIZON) | (facing.abs() < NEAR_PLANE)) << l;
    }
    (now, near)
}

/// [`masks_portable`] in AVX2, eight lanes at a time.
#[inline]
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn masks_avx2(
    h0: &[f32],
    h1: &[f32],
    step: &RowStep,
    normal: &[[f32; LANES]; 3],
) -> (u32, u32) {
    use std::arch::x86_64::*;
    assert!(h0.len() >= LANES && h1.len() >= LANES);
    let splat = |v: f64| _mm256_set1_ps(v as f32);
    let (el, f) = (splat(step.elevation), splat(step.between));
    let s = step.sun.map(splat);
    let (marker, zero) = (_mm256_set1_ps(-90.0), _mm256_setzero_ps());
    let magnitude = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
    let (near_horizon, near_plane) = (_mm256_set1_ps(NEAR_HORIZON), _mm256_set1_ps(NEAR_PLANE));
    let (mut now, mut near) = (0u32, 0u32);
    for o in [0, 8] {
        // SAFETY: o + 8 <= LANES values in each slice (asserted above).
        let (a, b) = unsafe {
            (
                _mm256_loadu_ps(h0.as_ptr().add(o)),
                _mm256_loadu_ps(h1.as_ptr().add(o)),
            )
        };
        let a2 = _mm256_blendv_ps(a, b, _mm256_cmp_ps::<_CMP_EQ_OQ>(a, marker));
        let b2 = _mm256_blendv_ps(b, a, _mm256_cmp_ps::<_CMP_EQ_OQ>(b, marker));
        let d = _mm256_sub_ps(
            el,
            _mm256_add_ps(a2, _mm256_mul_ps(f, _mm256_sub_ps(b2, a2))),
        );
        // SAFETY: as above, for the normals' rows of LANES values.
        let n = unsafe { [0, 1, 2].map(|axis| _mm256_loadu_ps(normal[axis].as_ptr().add(o))) };
        let facing = _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(n[0], s[0]), _mm256_mul_ps(n[1], s[1])),
            _mm256_mul_ps(n[2], s[2]),
        );
        let lit = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GT_OQ>(d, zero),
            _mm256_cmp_ps::<_CMP_GT_OQ>(facing, zero),
        );
        let close = _mm256_or_ps(
            _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_and_ps(d, magnitude), near_horizon),
            _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_and_ps(facing, magnitude), near_plane),
        );
        now |= (_mm256_movemask_ps(lit) as u32) << o;
        near |= (_mm256_movemask_ps(close) as u32) << o;
    }
    (now, near)
}

/// One row of posts as the kernel sums it (structure of arrays).
#[derive(Debug, Clone)]
pub struct ShadowRow<'a> {
    width: usize,
    /// The row's horizon angles, band after band (`bands x width`).
    angles: &'a [f32],
    /// Per chunk of [`LANES`] posts, an elevation (degrees) above which
    /// the sun lights every post of the chunk: above its highest horizon
    /// in any band and its steepest slope (`N . s >= sin(el - slope)`), with
    /// 0.001 degrees to spare; infinite for a chunk with nodata.
    clear_above: Vec<f64>,
    normal: [Vec<f64>; 3],
    normal32: [Vec<f32>; 3],
    /// Each post's lowest level of three (an index into the row's) and
    /// its Lagrange weights among them.
    base: Vec<usize>,
    level: Vec<[f64; LEVELS]>,
    /// `sums[x * KEPT + q]`: kept sum `q` (level-major) of post `x`, a
    /// post's together, so that a turn is a few vector additions.
    sums: Vec<f64>,
    /// The row's levels, `(first, count)` ([`super::levels_spanning`]).
    levels: (i64, usize),
    /// The days' running sums at their ends, summed, every level's: every
    /// post's, as if lit at every day's end (a post dark at an end takes
    /// that day's off).
    ends: Vec<f64>,
    diffuse_horizontal: f64,
    global_horizontal: Vec<f64>,
}

impl<'a> ShadowRow<'a> {
    /// A row of posts with unit `normals` (NaN for none) at heights `z`
    /// and horizon `angles` (band after band, `bands x width`, degrees,
    /// NaN for nodata), whose days will be taken at the levels `(first,
    /// count)`, which span every height of the row.
    pub fn new(normals: &[[f64; 3]], z: &[f32], angles: &'a [f32], levels: (i64, usize)) -> Self {
        let width = normals.len();
        assert!(angles.len().is_multiple_of(width.max(1)));
        let bands = angles.len() / width.max(1);
        let clear_above = (0..width / LANES)
            .map(|chunk| {
                let lanes = chunk * LANES..(chunk + 1) * LANES;
                let mut top = f64::NEG_INFINITY;
                for x in lanes {
                    let slope = normals[x][2].clamp(-1.0, 1.0).acos().to_degrees();
                    top = top.max(slope);
                    for b in 0..bands {
                        top = top.max(f64::from(angles[b * width + x]));
                    }
                    if slope.is_nan() || (0..bands).any(|b| angles[b * width + x].is_nan()) {
                        return f64::INFINITY;
                    }
                }
                top + NEAR_HORIZON as f64
            })
            .collect();
        let axis = |a: usize| normals.iter().map(|n| n[a]).collect::<Vec<f64>>();
        let normal = [axis(0), axis(1), axis(2)];
        let normal32 = [0, 1, 2].map(|a| normal[a].iter().map(|&v| v as f32).collect());
        let (base, level) = z
            .iter()
            .map(|&z| {
                let (lowest, weights) = levels_around(f64::from(z));
                // A post without a height keeps level 0 (its sums unread).
                let base = (lowest - levels.0).clamp(0, levels.1 as i64 - LEVELS as i64);
                (base as usize, weights)
            })
            .unzip();
        Self {
            width,
            angles,
            clear_above,
            normal32,
            normal,
            base,
            level,
            levels,
            sums: vec![0.0; KEPT * width],
            ends: vec![0.0; levels.1 * COMPONENTS],
            diffuse_horizontal: 0.0,
            global_horizontal: vec![0.0; levels.1],
        }
    }

    /// Forgets the days added so far (a new period).
    pub fn clear(&mut self) {
        self.sums.fill(0.0);
        self.ends.fill(0.0);
        self.diffuse_horizontal = 0.0;
        self.global_horizontal.fill(0.0);
    }

    /// Post `x`'s sums over the days added, at its own height.
    pub fn sums(&self, x: usize) -> Sums {
        let (l, base) = (self.level[x], self.base[x]);
        let mut out = Sums {
            diffuse_horizontal: self.diffuse_horizontal,
            global_horizontal: (0..LEVELS)
                .map(|i| l[i] * self.global_horizontal[base + i])
                .sum(),
            ..Sums::default()
        };
        let ends = &self.ends[base * COMPONENTS..][..KEPT];
        for (c, v) in out.sunlit.iter_mut().enumerate() {
            *v = (0..LEVELS)
                .map(|i| {
                    let q = i * COMPONENTS + c;
                    l[i] * (ends[q] + self.sums[x * KEPT + q])
                })
                .sum();
        }
        out
    }

    /// Adds `day` to every post.
    pub fn add_day(&mut self, day: &RowDay) {
        use crate::plumbing::simd::Level;
        match crate::plumbing::simd::level() {
            // SAFETY: `simd::level` found AVX-512, which the function is
            // compiled for.
            #[cfg(target_arch = "x86_64")]
            Level::Avx512 => unsafe { self.add_day_avx512(day) },
            // SAFETY: the same, for AVX2.
            #[cfg(target_arch = "x86_64")]
            Level::Avx2 => unsafe { self.add_day_avx2(day) },
            _ => self.add_day_portable(day),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn add_day_avx512(&mut self, day: &RowDay) {
        // SAFETY: AVX-512 F implies AVX2 (`simd::level` checks both).
        self.add_day_with(day, |a, b, s, n| unsafe { masks_avx2(a, b, s, n) });
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn add_day_avx2(&mut self, day: &RowDay) {
        // SAFETY: the function is compiled for AVX2, which the CPU has.
        self.add_day_with(day, |a, b, s, n| unsafe { masks_avx2(a, b, s, n) });
    }

    fn add_day_portable(&mut self, day: &RowDay) {
        self.add_day_with(day, masks_portable);
    }

    /// The day through every post, the chunks' steps tested by `masks`.
    #[inline(always)]
    fn add_day_with(&mut self, day: &RowDay, masks: impl Masks) {
        let w = self.width;
        assert_eq!((day.first, day.count), self.levels, "the row's levels");
        self.diffuse_horizontal += day.diffuse_horizontal;
        for (g, d) in self
            .global_horizontal
            .iter_mut()
            .zip(&day.global_horizontal)
        {
            *g += d;
        }
        let kept = day.count * COMPONENTS;
        let end = &day.prefix[day.steps.len() * kept..][..kept];
        for (e, d) in self.ends.iter_mut().zip(end) {
            *e += d;
        }
        let whole = w - w % LANES;
        for x0 in (0..whole).step_by(LANES) {
            self.add_day_lanes(x0, day, &masks);
        }
        for x in whole..w {
            self.add_day_post(x, day);
        }
    }

    /// Posts `x0..x0 + LANES` through the day.
    #[inline(always)]
    fn add_day_lanes(&mut self, x0: usize, day: &RowDay, masks: &impl Masks) {
        let (w, angles) = (self.width, self.angles);
        let clear_above = self.clear_above[x0 / LANES];
        let n32: [[f32; LANES]; 3] = [0, 1, 2].map(|a| {
            self.normal32[a][x0..x0 + LANES]
                .try_into()
                .expect("a whole chunk")
        });
        // Bit l: lane l is sunlit (kept in a register: a byte array here
        // stalled every step on a store the vector compare could not take).
        let mut lit = 0u32;
        for (k, step) in day.steps.iter().enumerate() {
            // Every lane lit, and the sun clear of every horizon and
            // slope of the chunk: nothing can change at this step.
            if lit == u32::MAX >> (32 - LANES) && step.elevation > clear_above {
                continue;
            }
            let (b0, b1) = (step.bands.0 as usize, step.bands.1 as usize);
            let h0 = &angles[b0 * w + x0..][..LANES];
            let h1 = &angles[b1 * w + x0..][..LANES];
            let (now, near) = masks(h0, h1, step, &n32);
            let mut todo = (now ^ lit) | near;
            while todo != 0 {
                let l = todo.trailing_zeros() as usize;
                todo &= todo - 1;
                let x = x0 + l;
                let state = if near >> l & 1 == 1 {
                    sunlit(h0[l], h1[l], step, self.normal_at(x))
                } else {
                    now >> l & 1 == 1
                };
                if state != (lit >> l & 1 == 1) {
                    self.turn(x, day, k, state);
                    lit ^= 1 << l;
                }
            }
        }
        // Dark at the day's end: the day's end, which `ends` counted, off.
        let mut dark = !lit & (u32::MAX >> (32 - LANES));
        while dark != 0 {
            let l = dark.trailing_zeros() as usize;
            dark &= dark - 1;
            self.add_running(x0 + l, day, day.steps.len(), -1.0);
        }
    }

    /// One post through the day, every step by [`sunlit`].
    fn add_day_post(&mut self, x: usize, day: &RowDay) {
        let (w, angles) = (self.width, self.angles);
        let normal = self.normal_at(x);
        let mut lit = false;
        for (k, step) in day.steps.iter().enumerate() {
            let (b0, b1) = (step.bands.0 as usize, step.bands.1 as usize);
            let state = sunlit(angles[b0 * w + x], angles[b1 * w + x], step, normal);
            if state != lit {
                self.turn(x, day, k, state);
                lit = state;
            }
        }
        if !lit {
            self.add_running(x, day, day.steps.len(), -1.0);
        }
    }

    fn normal_at(&self, x: usize) -> [f64; 3] {
        [self.normal[0][x], self.normal[1][x], self.normal[2][x]]
    }

    /// Post `x` comes into the sun (`lit`) or goes out of it at step `k`:
    /// a sunlit run from `a` to `b` adds the running sums at `b` less
    /// those at `a`.
    /// At step 0 the running sums are all zero: a post lit from the day's
    /// first step costs nothing until its sun goes.
    #[inline]
    fn turn(&mut self, x: usize, day: &RowDay, k: usize, lit: bool) {
        if k > 0 {
            self.add_running(x, day, k, if lit { -1.0 } else { 1.0 });
        }
    }

    /// Adds `sign` times the running sums before step `k` to post `x`.
    #[inline(always)]
    fn add_running(&mut self, x: usize, day: &RowDay, k: usize, sign: f64) {
        let at = day.before(k, self.base[x]);
        let sums: &mut [f64; KEPT] = (&mut self.sums[x * KEPT..][..KEPT])
            .try_into()
            .expect("KEPT");
        // Through a local array: the compiler, unsure the two do not
        // overlap once inlined, added them one by one.
        let mut local = *sums;
        for q in 0..KEPT {
            local[q] += sign * at[q];
        }
        *sums = local;
    }
}

#[cfg(test)]
mod tests {
    use super::super::{direct_irradiation, levels_spanning, ClearSky, Surface};
    use super::*;

    fn random_stream(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// A random row through a day of suns on every path this CPU has:
    /// each post's sums, turned into irradiation, equal the direct sum of
    /// the model over every step at the post's own height with the
    /// horizon as served; horizons placed within a hair of the sun and
    /// normals within a hair of its plane reach the `f64` test. Once with
    /// nodata and tall horizons (every step tested), once with low ones
    /// and none (the chunks skip the steps where the sun clears them).
    #[test]
    fn a_row_sums_as_each_post_step_by_step() {
        for (seed, nodata, tallest) in [(0x9e37_79b9_7f4a_7c15, true, 32.0), (7, false, 6.0)] {
            row_against_direct_sums(seed, nodata, tallest);
        }
    }

    /// `tallest`: the highest horizon, degrees; slopes reach as steep.
    fn row_against_direct_sums(seed: u64, nodata: bool, tallest: f64) {
        let mut random = random_stream(seed);
        let w = 16 * 5 + 7;
        let azimuths: Vec<f64> = (0..24).map(|i| f64::from(i) * 15.0 + 2.0).collect();
        let sky = ClearSky { linke: 3.3 };
        // A day at 46 N in June, steps of 10 minutes.
        let steps = super::super::day_steps(2026, 172, 10.0, 8.0);
        let z: Vec<f32> = (0..w).map(|_| (random() * 2000.0) as f32).collect();
        let (lo, hi) = z.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| {
            (a.min(f64::from(v)), b.max(f64::from(v)))
        });
        let levels = levels_spanning(lo, hi);
        let day = RowDay::new(&steps, (46.0, 0.0), &azimuths, sky, levels);
        let normals: Vec<[f64; 3]> = (0..w)
            .map(|x| match x % 9 {
                0 => [0.0, 0.0, 1.0],
                1 if nodata => [f64::NAN; 3],
                _ => {
                    let (slope, aspect) = (
                        random() * tallest.to_radians(),
                        random() * std::f64::consts::TAU,
                    );
                    [
                        slope.sin() * aspect.sin(),
                        slope.sin() * aspect.cos(),
                        slope.cos(),
                    ]
                }
            })
            .collect();
        let mut angles = vec![0f32; azimuths.len() * w];
        for (i, a) in angles.iter_mut().enumerate() {
            *a = match random() {
                v if v < 0.02 && nodata => f32::NAN,
                v if v < 0.06 => -90.0,
                v => (v * (tallest + 8.0) - 8.0) as f32,
            };
            // Some exactly at a sun elevation of the day.
            if i % 37 == 0 {
                *a = day.steps[i % day.steps.len()].elevation as f32;
            }
        }
        let mut paths = vec!["dispatched", "portable"];
        #[cfg(target_arch = "x86_64")]
        if crate::plumbing::simd::level() >= crate::plumbing::simd::Level::Avx2 {
            paths.push("avx2");
        }
        for name in paths {
            let mut row = ShadowRow::new(&normals, &z, &angles, levels);
            match name {
                "dispatched" => row.add_day(&day),
                "portable" => row.add_day_portable(&day),
                // SAFETY: the CPU has AVX2.
                #[cfg(target_arch = "x86_64")]
                _ => unsafe { row.add_day_avx2(&day) },
                #[cfg(not(target_arch = "x86_64"))]
                _ => unreachable!(),
            }
            let mut compared = 0;
            for x in 0..w {
                if normals[x][2].is_nan() {
                    continue;
                }
                let surface = Surface {
                    normal: normals[x],
                    svf_cosine: 0.5 + 0.5 * random(),
                    albedo: 0.2,
                };
                let got = row.sums(x).irradiation(&surface);
                let want = direct_irradiation(&day, sky, f64::from(z[x]), &surface, |s| {
                    let (b0, b1) = (s.bands.0 as usize, s.bands.1 as usize);
                    sunlit(angles[b0 * w + x], angles[b1 * w + x], s, normals[x])
                });
                // Exactly the same steps (the levels' weights sum to 1).
                assert!(
                    (got.sunlit_steps - want.sunlit_steps).abs() < 1e-9,
                    "{name} post {x}: {} sunlit steps against {}",
                    got.sunlit_steps,
                    want.sunlit_steps
                );
                for (what, g, v) in [
                    ("beam", got.beam, want.beam),
                    ("diffuse", got.diffuse, want.diffuse),
                    ("reflected", got.reflected, want.reflected),
                ] {
                    assert!(
                        (g - v).abs() <= 2e-4 * v.abs().max(100.0),
                        "{name} post {x} {what}: {g} against {v}"
                    );
                }
                compared += 1;
            }
            assert!(compared > 60, "{name}: {compared}");
        }
    }
}
