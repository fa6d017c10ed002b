//! Horizon angles at every post in `S` azimuths: the algorithms the
//! `horizons` stage ([`crate::stages::horizons`]) runs, band by band.
//! `docs/HORIZONS.md` is the long form.
//!
//! Three methods, each exact for its own definition (see the modules):
//!
//! - [`line`](mod@line): the steepest sight line along the straight line from the
//!   post, on the surface the tracers use (Timonen 2013's sweeps, along grid
//!   directions so that every post is on a line);
//! - [`sector`]: Stewart's (1998) maximum over the closed azimuth wedge,
//!   with his tree of upper convex hulls;
//! - [`sampled`]: centre-line sampling with nearest-post heights, the
//!   baseline other tools use (comparison only).
//!
//! [`brute`] has one-post-at-a-time references for `line` and `sector`,
//! which the tests hold the fast algorithms to.
//!
//! [`sky`] integrates stored horizons into sky-view factors and sky light.

pub mod brute;
pub mod features;
pub mod fourier;
pub mod line;
pub mod sampled;
pub mod sector;
pub mod sky;

use rayon::prelude::*;

use crate::terrain::steepest::{self, Tag};
use crate::terrain::Terrain;
use line::GridDirection;

/// Which definition of the horizon.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Steepest sight line along the line in each direction (exact, fast).
    Line,
    /// Stewart's sector maximum over each closed azimuth wedge (exact).
    Sector,
    /// Centre-line sampling, nearest post (baseline, approximate).
    Sampled,
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown method {s:?} (line, sector, sampled)"))
    }
}

impl Method {
    pub const ALL: [Method; 3] = [Method::Line, Method::Sector, Method::Sampled];

    pub const fn name(self) -> &'static str {
        match self {
            Method::Line => "line",
            Method::Sector => "sector",
            Method::Sampled => "sampled",
        }
    }
}

/// One output band: what it looks at and the azimuth interval it covers.
#[derive(Debug, Clone)]
pub struct Band {
    /// Compass azimuth of the band, degrees.
    pub azimuth: f64,
    /// The azimuth interval the band stands for (`lo < hi`, may wrap).
    pub lo: f64,
    pub hi: f64,
    pub kind: BandKind,
}

#[derive(Debug, Clone)]
pub enum BandKind {
    Line(GridDirection),
    Sector { index: usize, count: usize },
    Sampled,
}

/// The azimuth interval each band stands for: half way to its neighbours
/// (for sectors, exactly the sector).
pub fn band_bounds(azimuths: &[f64]) -> Vec<(f64, f64)> {
    let n = azimuths.len();
    (0..n)
        .map(|i| {
            let back = (azimuths[i] - azimuths[(i + n - 1) % n]).rem_euclid(360.0);
            let ahead = (azimuths[(i + 1) % n] - azimuths[i]).rem_euclid(360.0);
            (azimuths[i] - back / 2.0, azimuths[i] + ahead / 2.0)
        })
        .collect()
}

/// The bands of `count` azimuths for `method` on posts `dx x dy` apart.
/// `tolerance`: how far (degrees) a line direction may sit from its nominal
/// azimuth (default: an eighth of the spacing).
pub fn plan_bands(
    method: Method,
    count: usize,
    dx: f64,
    dy: f64,
    tolerance: Option<f64>,
) -> Vec<Band> {
    let kinds: Vec<(f64, BandKind)> = match method {
        Method::Sector => (0..count)
            .map(|i| {
                (
                    i as f64 * 360.0 / count as f64,
                    BandKind::Sector { index: i, count },
                )
            })
            .collect(),
        Method::Sampled => (0..count)
            .map(|i| (i as f64 * 360.0 / count as f64, BandKind::Sampled))
            .collect(),
        Method::Line => {
            let tol = tolerance.unwrap_or_else(|| line::default_tolerance(count));
            let mut dirs: Vec<_> = line::grid_directions(count, dx, dy, tol)
                .into_iter()
                .map(|d| (d.azimuth, BandKind::Line(d)))
                .collect();
            // Compass order by the step's own azimuth, which every reader
            // of `band_azimuths` assumes: where the grid has no step near
            // the last nominal azimuths (over about 800 bands) they fall
            // back to the step at 0, which would otherwise sit last.
            dirs.sort_by(|a, b| a.0.total_cmp(&b.0));
            // Each grid step once. Where the grid cannot give every asked
            // azimuth a step of its own within the tolerance (near the
            // axes past about 800 directions, whose steps are at most
            // [`line::MAX_STEP`] long; sooner on cells of 50 x 93 m at 57
            // N), neighbouring azimuths fall back to one step: a band
            // twice over is the same angles in twice the time and bytes,
            // and an azimuth coordinate that repeats (the xarray backend's).
            // Sorted, the repeats are neighbours.
            dirs.dedup_by(|a, b| match (&a.1, &b.1) {
                (BandKind::Line(x), BandKind::Line(y)) => x.step == y.step,
                _ => false,
            });
            dirs
        }
    };
    let azimuths: Vec<f64> = kinds.iter().map(|k| k.0).collect();
    kinds
        .into_iter()
        .zip(band_bounds(&azimuths))
        .map(|((azimuth, kind), (lo, hi))| Band {
            azimuth,
            lo,
            hi,
            kind,
        })
        .collect()
}

/// Options that change every band's values; the default is exact: the
/// whole DEM, with Stewart's narrow-sector check.
#[derive(Debug, Clone, Copy)]
pub struct BandOptions {
    /// Metres; `None`: the whole DEM (exact).
    pub max_distance: Option<f64>,
    /// Stewart's narrow-sector check (sec. IV-E), for `sector`.
    pub narrow_check: bool,
}

impl Default for BandOptions {
    fn default() -> Self {
        Self {
            max_distance: None,
            narrow_check: true,
        }
    }
}

/// The horizon angles (degrees; NaN for nodata) of one band at every post,
/// and a count of the work done (hull vertices, tree steps or samples).
pub fn band_horizons(terrain: &Terrain, band: &Band, opts: BandOptions) -> (Vec<f32>, u64) {
    band_horizons_rows(terrain, band, opts, [0..terrain.height, 0..terrain.width])
}

/// [`band_horizons`] where only rows `rows` and columns `cols` must be
/// exact: bounded `line` computes those posts alone (NaN elsewhere), and may
/// be given a window of the DEM's rows that holds them and the rows within
/// reach (its output is then the window's rows); the other methods compute
/// every post of a whole DEM.
pub(crate) fn band_horizons_rows(
    terrain: &Terrain,
    band: &Band,
    opts: BandOptions,
    area: [std::ops::Range<usize>; 2],
) -> (Vec<f32>, u64) {
    let mut out = vec![0f32; terrain.z.len()];
    let work = band_horizons_into(
        terrain,
        band,
        opts,
        area,
        (&mut out, None),
        sector::Shared::default(),
    );
    (out, work)
}

/// [`band_horizons_rows`] into `out` (one value per post of `terrain`),
/// and where `distances` is given (the same shape), each post's horizontal
/// distance in metres to the point that sets its horizon: exact for
/// `line`, the arg-max post for `sector`, the steepest sample for
/// `sampled`; NaN for nodata and where nothing lies ahead. Unbounded
/// `sector` takes its sorted orders from `shared` where they fit
/// ([`sector::Ranks`]). Returns the count of work done.
pub fn band_horizons_into(
    terrain: &Terrain,
    band: &Band,
    opts: BandOptions,
    [rows, cols]: [std::ops::Range<usize>; 2],
    (out, distances): (&mut [f32], Option<&mut [f32]>),
    shared: sector::Shared,
) -> u64 {
    let windowed = terrain.row0 > 0 || terrain.z.len() < terrain.width * terrain.height;
    assert!(
        !windowed || (matches!(band.kind, BandKind::Line(_)) && opts.max_distance.is_some()),
        "only bounded line horizons run over a window of rows"
    );
    assert_eq!(out.len(), terrain.z.len());
    match &band.kind {
        BandKind::Line(dir) => match opts.max_distance {
            None => line::line_horizons_with_distances(terrain, dir, out, distances).vertices,
            Some(max) => {
                let stencil = line::Stencil::new(dir.step);
                let lengths = line::step_lengths(
                    dir.step,
                    terrain.height,
                    (terrain.dx, terrain.dy),
                    terrain.row_scale,
                );
                let (w, line) = (terrain.width, (&stencil, &lengths[..]));
                let area = (&rows, &cols);
                match distances {
                    Some(d) => out
                        .par_chunks_mut(w)
                        .zip(d.par_chunks_mut(w))
                        .enumerate()
                        .for_each(|(i, (out, d))| {
                            bounded_line_row::<Option<f64>>(
                                terrain,
                                line,
                                max,
                                i,
                                area,
                                out,
                                Some(d),
                            )
                        }),
                    None => out.par_chunks_mut(w).enumerate().for_each(|(i, out)| {
                        bounded_line_row::<()>(terrain, line, max, i, area, out, None)
                    }),
                }
                0
            }
        },
        BandKind::Sector { index, count } => {
            let s = match opts.max_distance {
                None => sector::sector_horizons_at(
                    terrain,
                    (*index, *count),
                    opts.narrow_check,
                    (crate::plumbing::simd::level(), shared),
                    out,
                    distances,
                ),
                Some(max) => sector::sector_horizons_within(
                    terrain,
                    (*index, *count),
                    opts.narrow_check,
                    max,
                    [0..terrain.height, cols.clone()],
                    out,
                    distances,
                ),
            };
            s.tangent_steps + s.inserts
        }
        BandKind::Sampled => {
            sampled::sampled_horizons(
                terrain,
                band.azimuth,
                opts.max_distance.unwrap_or(f64::INFINITY),
                out,
                distances,
            );
            0
        }
    }
}

/// Bounded line horizons of the window's row `i` into `out`, for the posts
/// in `rows` x `cols` (NaN elsewhere), and their distances where asked:
/// the walk keeps `T` of each post's steepest point (`()` without
/// distances).
fn bounded_line_row<T: Tag<f64>>(
    terrain: &Terrain,
    (stencil, lengths): (&line::Stencil, &[f64]),
    max_distance: f64,
    i: usize,
    (rows, cols): (&std::ops::Range<usize>, &std::ops::Range<usize>),
    out: &mut [f32],
    mut distances: Option<&mut [f32]>,
) {
    let row = terrain.row0 + i;
    for (col, v) in out.iter_mut().enumerate() {
        let (angle, steepest) = if rows.contains(&row) && cols.contains(&col) {
            line::line_horizon_within::<T>(
                terrain,
                stencil,
                lengths,
                (col as i64, row as i64),
                max_distance,
            )
        } else {
            (f32::NAN, T::default())
        };
        *v = angle;
        if let Some(d) = distances.as_deref_mut() {
            d[col] = steepest::metres(steepest);
        }
    }
}
