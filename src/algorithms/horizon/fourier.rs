//! Horizons as a few Fourier coefficients per post: the stored bands of a
//! post, `h(a_i)` at its band azimuths `a_i`, fitted by least squares with
//! the trigonometric polynomial
//!
//! ```text
//! h(a) = c_0 + sum_{k=1..K} c_{2k-1} cos(k a) + c_{2k} sin(k a)      (a: compass, radians)
//! ```
//!
//! `2K + 1` numbers per post instead of `N` bands, for shaders that want the
//! horizon at any azimuth from a few texture reads (`export --layer horizon
//! --fourier K -o X.ktx2`). The bands of `line` sit at the grid directions'
//! azimuths, not evenly, so the fit is least squares through one
//! pseudo-inverse shared by every post (`(A^T A)^-1 A^T`, `2K + 1` by `N`),
//! not a DFT; on even azimuths the two agree. `2K + 1 <= N`: past that the
//! system is underdetermined. What the coefficients cost is charted by
//! `terrabake-bench horizons --fourier` against the stored bands (docs/BENCHMARKS.md).

use crate::error::bail;

/// The least-squares fit of `K` harmonics at a layer's band azimuths.
#[derive(Debug, Clone)]
pub struct FourierBasis {
    harmonics: usize,
    /// The basis functions at each band azimuth (the design matrix).
    rows: Vec<Vec<f64>>,
    /// Rows of the pseudo-inverse: coefficient `j` is `pinv[j] . h`.
    pinv: Vec<Vec<f64>>,
}

/// The basis functions at compass azimuth `a` (radians): `1, cos a, sin a,
/// cos 2a, sin 2a, ...`, `2K + 1` of them.
fn basis(a: f64, harmonics: usize) -> Vec<f64> {
    let mut row = vec![1.0];
    for k in 1..=harmonics {
        let (s, c) = (k as f64 * a).sin_cos();
        row.push(c);
        row.push(s);
    }
    row
}

impl FourierBasis {
    /// The fit of `harmonics` harmonics at `azimuths` (compass degrees).
    pub fn new(azimuths: &[f64], harmonics: usize) -> crate::Result<Self> {
        let n = 2 * harmonics + 1;
        if n > azimuths.len() {
            bail!(
                "{harmonics} harmonics need {n} coefficients, more than the layer's {} bands: give at most {}",
                azimuths.len(),
                (azimuths.len() - 1) / 2
            );
        }
        let rows: Vec<Vec<f64>> = azimuths
            .iter()
            .map(|a| basis(a.to_radians(), harmonics))
            .collect();
        // Normal equations A^T A x = A^T, solved by Gauss-Jordan with
        // partial pivoting (n is at most a few dozen).
        let mut m: Vec<Vec<f64>> = (0..n)
            .map(|i| {
                let mut row: Vec<f64> = (0..n)
                    .map(|j| rows.iter().map(|r| r[i] * r[j]).sum())
                    .collect();
                row.extend(rows.iter().map(|r| r[i]));
                row
            })
            .collect();
        for col in 0..n {
            let pivot = (col..n)
                .max_by(|&a, &b| m[a][col].abs().total_cmp(&m[b][col].abs()))
                .expect("rows left");
            if m[pivot][col].abs() < 1e-9 * azimuths.len() as f64 {
                bail!("the band azimuths cannot separate {harmonics} harmonics (they repeat or bunch)");
            }
            m.swap(col, pivot);
            let p = m[col][col];
            m[col].iter_mut().for_each(|v| *v /= p);
            for i in (0..n).filter(|&i| i != col) {
                let f = m[i][col];
                if f != 0.0 {
                    let pivot_row = m[col].clone();
                    m[i].iter_mut()
                        .zip(&pivot_row)
                        .for_each(|(v, p)| *v -= f * p);
                }
            }
        }
        Ok(Self {
            harmonics,
            rows,
            pinv: m.into_iter().map(|row| row[n..].to_vec()).collect(),
        })
    }

    /// Coefficients per post: `2K + 1`.
    pub fn len(&self) -> usize {
        2 * self.harmonics + 1
    }

    pub fn is_empty(&self) -> bool {
        false
    }

    /// The coefficients of one post's bands `angles` (degrees, one per
    /// azimuth) into `out` (`len()`); NaN for a nodata post.
    pub fn fit(&self, angles: &[f32], out: &mut [f32]) {
        if angles.iter().any(|a| a.is_nan()) {
            out.fill(f32::NAN);
            return;
        }
        for (o, row) in out.iter_mut().zip(&self.pinv) {
            *o = row
                .iter()
                .zip(angles)
                .map(|(p, &a)| p * f64::from(a))
                .sum::<f64>() as f32;
        }
    }

    /// The horizons (degrees) that `coefficients` give at the band
    /// azimuths the basis was made for, into `out`.
    pub fn reconstruct(&self, coefficients: &[f32], out: &mut [f64]) {
        for (o, row) in out.iter_mut().zip(&self.rows) {
            *o = row
                .iter()
                .zip(coefficients)
                .map(|(b, &c)| b * f64::from(c))
                .sum();
        }
    }

    /// The horizon (degrees) that `coefficients` give at compass `azimuth`
    /// (degrees).
    pub fn evaluate(&self, coefficients: &[f32], azimuth: f64) -> f64 {
        basis(azimuth.to_radians(), self.harmonics)
            .iter()
            .zip(coefficients)
            .map(|(b, &c)| b * f64::from(c))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uneven azimuths, as a line bake's grid directions are.
    fn azimuths(n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| i as f64 * 360.0 / n as f64 + 3.0 * ((i * 7) % 5) as f64 / 5.0)
            .collect()
    }

    #[test]
    fn a_trigonometric_polynomial_is_fitted_exactly() {
        let az = azimuths(16);
        let f = FourierBasis::new(&az, 3).unwrap();
        let h = |a: f64| {
            let a = a.to_radians();
            5.0 + 2.0 * a.cos() - 1.5 * (2.0 * a).sin() + 0.25 * (3.0 * a).cos()
        };
        let angles: Vec<f32> = az.iter().map(|&a| h(a) as f32).collect();
        let mut c = vec![0f32; f.len()];
        f.fit(&angles, &mut c);
        let want = [5.0, 2.0, 0.0, 0.0, -1.5, 0.25, 0.0];
        for (got, want) in c.iter().zip(want) {
            assert!((f64::from(*got) - want).abs() < 1e-5, "{c:?}");
        }
        // And anywhere between the bands.
        for a in [1.0, 100.5, 271.3] {
            assert!((f.evaluate(&c, a) - h(a)).abs() < 1e-4);
        }
    }

    #[test]
    fn more_harmonics_never_fit_worse_and_too_many_are_refused() {
        let az = azimuths(12);
        let angles: Vec<f32> = (0..12).map(|i| ((i * 37 % 11) as f32) - 3.0).collect();
        let mut last = f64::INFINITY;
        for k in 0..=5 {
            let f = FourierBasis::new(&az, k).unwrap();
            let mut c = vec![0f32; f.len()];
            f.fit(&angles, &mut c);
            let mut back = vec![0f64; az.len()];
            f.reconstruct(&c, &mut back);
            let sq: f64 = back
                .iter()
                .zip(&angles)
                .map(|(&b, &h)| (b - f64::from(h)).powi(2))
                .sum();
            // The same as evaluating at each azimuth.
            assert!((back[3] - f.evaluate(&c, az[3])).abs() < 1e-9);
            assert!(sq <= last + 1e-6, "{k}: {sq} after {last}");
            last = sq;
        }
        assert!(FourierBasis::new(&az, 6).is_err());
    }
}
