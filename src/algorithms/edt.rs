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

/// The lower envelope of the parabolas `y = (x - q)^2 + f_q` (in sample
/// units), built left to right from samples in increasing `q` (Felzenszwalb
/// and Huttenlocher, Algorithm 1): the scratch of a 1-D transform, reused
/// across rows so that it allocates once per thread.
#[derive(Debug, Default, Clone)]
pub struct Envelope {
    parabolas: Vec<Parabola>,
}

#[derive(Debug, Clone, Copy)]
struct Parabola {
    root: f64,
    offset: f64,
    /// `offset + root^2`: two parabolas meet at `(key - key') / (2 (root - root'))`.
    key: f64,
    /// Where the parabola starts to be the lowest.
    from: f64,
}

impl Envelope {
    pub fn clear(&mut self) {
        self.parabolas.clear();
    }

    /// Adds the parabola rooted at `q` (greater than every root so far) with
    /// offset `f` (finite).
    #[inline]
    pub fn push(&mut self, q: f64, f: f64) {
        let key = f + q * q;
        let mut from = f64::NEG_INFINITY;
        while let Some(last) = self.parabolas.last() {
            // Where the new parabola meets the last one: after the point
            // where the last one became the lowest, or the last one is
            // never the lowest.
            let s = (key - last.key) / (2.0 * (q - last.root));
            if s > last.from {
                from = s;
                break;
            }
            self.parabolas.pop();
        }
        self.parabolas.push(Parabola {
            root: q,
            offset: f,
            key,
            from,
        });
    }

    pub fn is_empty(&self) -> bool {
        self.parabolas.is_empty()
    }

    /// Calls `visit(p, d)` for every `p` of `positions` (increasing) with
    /// `d` the envelope at `p`; the envelope must not be empty.
    #[inline]
    pub(crate) fn evaluate_at(
        &self,
        positions: impl Iterator<Item = usize>,
        mut visit: impl FnMut(usize, f64),
    ) {
        let (first, rest) = self.parabolas.split_first().expect("a parabola");
        let mut lowest = first;
        let mut next = rest.iter().peekable();
        for p in positions {
            let pf = p as f64;
            while let Some(n) = next.next_if(|n| n.from < pf) {
                lowest = n;
            }
            let d = pf - lowest.root;
            visit(p, d * d + lowest.offset);
        }
    }

    /// Calls `visit(p, d)` for `p` in `0..n` with `d` the envelope at `p`
    /// (`inf` everywhere when it is empty).
    #[inline]
    pub fn evaluate(&self, n: usize, mut visit: impl FnMut(usize, f64)) {
        if self.is_empty() {
            (0..n).for_each(|p| visit(p, f64::INFINITY));
        } else {
            self.evaluate_at(0..n, visit);
        }
    }
}

/// 1-D squared distance transform: `out[p] = min_q (spacing (p - q))^2 + f[q]`,
/// `f[q] = inf` where there is no sample; `out` is `inf` where `f` is all
/// `inf`.
pub(crate) fn squared_1d(f: &[f64], spacing: f64, out: &mut [f64], envelope: &mut Envelope) {
    let s2 = spacing * spacing;
    envelope.clear();
    for (q, &fq) in f.iter().enumerate() {
        if fq != f64::INFINITY {
            envelope.push(q as f64, fq / s2);
        }
    }
    envelope.evaluate(out.len(), |p, d| out[p] = d * s2);
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
        || (Vec::new(), Envelope::default()),
        |(f, envelope), (x, col)| {
            f.clear();
            f.extend((0..height).map(|y| {
                if site[y * width + x] {
                    0.0
                } else {
                    f64::INFINITY
                }
            }));
            squared_1d(f, dy, col, envelope);
        },
    );
    let mut out = vec![0f64; width * height];
    out.par_chunks_mut(width).enumerate().for_each_init(
        || (Vec::new(), Envelope::default()),
        |(f, envelope), (y, row)| {
            f.clear();
            f.extend((0..width).map(|x| cols[x * height + y]));
            squared_1d(f, dx, row, envelope);
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
