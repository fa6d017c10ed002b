//! Exact Euclidean distance transforms of bit planes, in linear time: the
//! building block of the parameter planes (Paglieroni and Petersen 1992,
//! sec. 2.1, eq. 4: the distance from each cell to the nearest cell of a
//! horizontal slice).
//!
//! Felzenszwalb and Huttenlocher's separable algorithm ("Distance Transforms
//! of Sampled Functions", Theory of Computing 8, 2012, sec. 2-3): the squared
//! distance transform of a 2-D grid is a 1-D transform of every column,
//! then of every row of the result; each 1-D transform is the lower envelope
//! of parabolas rooted at the samples, found in one left-to-right pass. We
//! take the spacing of each axis (`dx`, `dy`, which may differ) into the
//! parabolas, so distances come out in metres rather than in cells, and we
//! skip samples at infinity instead of letting `inf - inf` poison the
//! envelope. Rows and columns run in parallel.

use rayon::prelude::*;

/// 1-D squared distance transform: `out[p] = min_q (spacing (p - q))^2 + f[q]`,
/// `f[q] = inf` where there is no sample; `out` is `inf` where `f` is all
/// `inf`. `v` and `z` are scratch space of `f.len()` and `f.len() + 1`.
pub fn squared_1d(f: &[f64], spacing: f64, out: &mut [f64], v: &mut Vec<usize>, z: &mut Vec<f64>) {
    let s2 = spacing * spacing;
    v.clear();
    z.clear();
    // Intersection of the parabolas rooted at q and at v (in sample units).
    let meet = |q: usize, r: usize| {
        let (qf, rf) = (q as f64, r as f64);
        ((f[q] / s2 + qf * qf) - (f[r] / s2 + rf * rf)) / (2.0 * (qf - rf))
    };
    for (q, &fq) in f.iter().enumerate() {
        if fq == f64::INFINITY {
            continue;
        }
        loop {
            match v.last() {
                None => {
                    v.push(q);
                    z.push(f64::NEG_INFINITY);
                    break;
                }
                Some(&r) => {
                    let s = meet(q, r);
                    if s <= *z.last().expect("z follows v") {
                        v.pop();
                        z.pop();
                    } else {
                        v.push(q);
                        z.push(s);
                        break;
                    }
                }
            }
        }
    }
    if v.is_empty() {
        out.iter_mut().for_each(|o| *o = f64::INFINITY);
        return;
    }
    z.push(f64::INFINITY);
    let mut k = 0;
    for (p, o) in out.iter_mut().enumerate() {
        let pf = p as f64;
        while z[k + 1] < pf {
            k += 1;
        }
        let d = pf - v[k] as f64;
        *o = s2 * d * d + f[v[k]];
    }
}

/// Squared Euclidean distance, in metres², from every cell of a `width x
/// height` row-major grid to the nearest cell where `site` is true (`inf`
/// when there is none); cells are `dx` apart along rows and `dy` along
/// columns.
pub fn squared_2d(site: &[bool], width: usize, height: usize, dx: f64, dy: f64) -> Vec<f64> {
    assert_eq!(site.len(), width * height, "grid is {width} x {height}");
    // Columns first, into a column-major buffer so both passes read contiguously.
    let mut cols = vec![0f64; width * height];
    cols.par_chunks_mut(height).enumerate().for_each_init(
        || (Vec::new(), Vec::new(), Vec::new()),
        |(f, v, z), (x, col)| {
            f.clear();
            f.extend((0..height).map(|y| {
                if site[y * width + x] {
                    0.0
                } else {
                    f64::INFINITY
                }
            }));
            squared_1d(f, dy, col, v, z);
        },
    );
    let mut out = vec![0f64; width * height];
    out.par_chunks_mut(width).enumerate().for_each_init(
        || (Vec::new(), Vec::new(), Vec::new()),
        |(f, v, z), (y, row)| {
            f.clear();
            f.extend((0..width).map(|x| cols[x * height + y]));
            squared_1d(f, dx, row, v, z);
        },
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The definition, O(n^2).
    fn brute(site: &[bool], w: usize, h: usize, dx: f64, dy: f64) -> Vec<f64> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                (0..w * h)
                    .filter(|&j| site[j])
                    .map(|j| {
                        let (ex, ey) = ((x - (j % w) as f64) * dx, (y - (j / w) as f64) * dy);
                        ex * ex + ey * ey
                    })
                    .fold(f64::INFINITY, f64::min)
            })
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]
        #[test]
        fn equals_brute_force(w in 1usize..24, h in 1usize..24, density in 0.0f64..0.5, seed in any::<u64>(), dx in 0.5f64..100.0, dy in 0.5f64..100.0) {
            let mut state = seed;
            let site: Vec<bool> = (0..w * h)
                .map(|_| {
                    state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    ((state >> 11) as f64 / (1u64 << 53) as f64) < density
                })
                .collect();
            let (got, want) = (squared_2d(&site, w, h, dx, dy), brute(&site, w, h, dx, dy));
            for (i, (g, e)) in got.iter().zip(&want).enumerate() {
                prop_assert!(g == e || (g - e).abs() <= 1e-9 * e, "cell {i}: {g} != {e}");
            }
        }
    }

    #[test]
    fn integer_spacing_is_exact_and_empty_planes_are_infinite() {
        let mut site = vec![false; 7 * 5];
        site[2 * 7 + 3] = true;
        let d = squared_2d(&site, 7, 5, 3.0, 2.0);
        assert_eq!(d[0], (3.0 * 3.0f64).powi(2) + (2.0 * 2.0f64).powi(2));
        assert_eq!(d[2 * 7 + 3], 0.0);
        assert!(squared_2d(&[false; 12], 4, 3, 1.0, 1.0)
            .iter()
            .all(|v| v.is_infinite()));
    }
}
