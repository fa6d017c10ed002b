//! The horizon methods' speed against their accuracy (`terrabake
//! terrabake-bench horizons`): the chart a user reads to choose a method and `S`.
//!
//! **Reference.** Line horizons in 1024 grid directions (each within 0.1
//! degree of `i * 360 / 1024`): exact sight lines, dense in azimuth.
//! **Error.** On the central half of a crop (every post of the crop
//! occludes), each method's horizon at each reference azimuth against the
//! reference there: a sector's value is its wedge's, as its definition
//! says; line and sampled directions interpolate linearly between their
//! two neighbours, as `lit_fraction` does. Sky-view factor (Zakšek's, the
//! GIS one) from each method's own bands against the reference's.
//! **Time.** Wall seconds for all bands of the crop on all cores.

use std::path::Path;
use std::time::Instant;

use anyhow::Result;
use rayon::prelude::*;
use serde::Serialize;
use terrabake_format::horizons::{bands_around, between};

use super::chart::{log_log_svg, log_log_svg_with_marks, Series};
use super::markdown_table;
use super::peers::{LoadedPeer, PeerManifest, PeerRow, SvfDefinition};
use terrabake::algorithms::horizon::sky::{
    sums_of_horizons, svf_of_horizons, BandIntegrals, SkySums,
};
use terrabake::algorithms::horizon::{
    band_horizons, plan_bands, Band, BandKind, BandOptions, Method,
};
use terrabake::terrain::Terrain;

/// Every band of `bands` on `terrain` (all cores), the wall time and the
/// work counted by the algorithms.
pub fn all_bands(
    terrain: &Terrain,
    bands: &[Band],
    opts: BandOptions,
) -> (Vec<Vec<f32>>, f64, u64) {
    let start = Instant::now();
    let results: Vec<(Vec<f32>, u64)> = bands
        .par_iter()
        .map(|b| band_horizons(terrain, b, opts))
        .collect();
    let seconds = start.elapsed().as_secs_f64();
    let work = results.iter().map(|r| r.1).sum();
    (results.into_iter().map(|r| r.0).collect(), seconds, work)
}

/// One method and band count, timed on a whole DEM.
#[derive(Debug, Clone, Serialize)]
pub struct SpeedRow {
    pub method: String,
    pub bands: usize,
    pub posts: usize,
    pub seconds: f64,
    /// Post-bands per second, all cores.
    pub post_bands_per_second: f64,
    /// Hull vertices (line) or tree steps and inserts (sector) per post-band.
    pub work_per_post_band: f64,
}

pub fn speed(terrain: &Terrain, runs: &[(Method, usize)]) -> Vec<SpeedRow> {
    runs.iter()
        .map(|&(method, count)| {
            let bands = plan_bands(method, count, terrain.dx, terrain.dy, None);
            let (_, seconds, work) = all_bands(terrain, &bands, BandOptions::default());
            let pb = (terrain.z.len() * count) as f64;
            SpeedRow {
                method: method.name().into(),
                bands: count,
                posts: terrain.z.len(),
                seconds,
                post_bands_per_second: pb / seconds,
                work_per_post_band: work as f64 / pb,
            }
        })
        .collect()
}

/// One method and band count against the reference.
#[derive(Debug, Clone, Serialize)]
pub struct AccuracyRow {
    pub method: String,
    pub bands: usize,
    /// How far a line direction was let sit from its nominal azimuth
    /// (`None`: the stage's default, an eighth of the spacing).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub direction_tolerance_deg: Option<f64>,
    pub seconds: f64,
    /// Root mean square and mean (bias) of the horizon angle error, degrees.
    pub horizon_rms_deg: f64,
    pub horizon_bias_deg: f64,
    /// Root mean square and largest error of the sky-view factor.
    pub svf_rms: f64,
    pub svf_max: f64,
}

impl AccuracyRow {
    /// The method as the tables name it, with a tolerance that is not the
    /// default.
    fn label(&self) -> String {
        match self.direction_tolerance_deg {
            Some(t) => format!("{} within {t} deg", self.method),
            None => self.method.clone(),
        }
    }
}

/// Zakšek's svf at `post` of band-major `values` in the bands of `integrals`.
pub(super) fn svf_of(integrals: &[BandIntegrals], values: &[Vec<f32>], post: usize) -> f64 {
    svf_of_horizons(integrals, values.iter().map(|v| f64::from(v[post])))
}

fn integrals(bands: &[Band]) -> Vec<BandIntegrals> {
    bands
        .iter()
        .map(|b| BandIntegrals::new(b.lo, b.hi))
        .collect()
}

/// The reference on `terrain`: its bands and values, the posts the errors
/// are taken at (the central half) and its sky-view factor there in both
/// definitions (Zakšek's over the horizontal; the slope-aware cosine one).
#[derive(Debug)]
pub struct Reference {
    pub(super) bands: Vec<Band>,
    pub(super) values: Vec<Vec<f32>>,
    pub(super) posts: Vec<usize>,
    pub(super) svf: Vec<f64>,
    pub(super) svf_cosine: Vec<f64>,
    pub seconds: f64,
}

impl Reference {
    pub fn new(terrain: &Terrain, count: usize) -> Self {
        let bands = plan_bands(Method::Line, count, terrain.dx, terrain.dy, Some(0.1));
        let (values, seconds, _) = all_bands(terrain, &bands, BandOptions::default());
        let (w, h) = (terrain.width, terrain.height);
        let posts: Vec<usize> = (h / 4..h - h / 4)
            .flat_map(|r| (w / 4..w - w / 4).map(move |c| r * w + c))
            .filter(|&i| !terrain.z[i].is_nan())
            .collect();
        let integrals = integrals(&bands);
        let sums: Vec<SkySums> = posts
            .iter()
            .map(|&p| {
                let normal = terrain.normal(p % w, p / w).expect("a post with a height");
                sums_of_horizons(&integrals, values.iter().map(|v| f64::from(v[p])), normal)
            })
            .collect();
        Self {
            bands,
            values,
            posts,
            svf: sums.iter().map(SkySums::svf).collect(),
            svf_cosine: sums.iter().map(SkySums::svf_cosine).collect(),
            seconds,
        }
    }

    /// RMS and mean of `estimate(post, azimuth) - reference` over every
    /// reference azimuth and post, degrees.
    pub(super) fn horizon_errors(&self, estimate: impl Fn(usize, f64) -> f64) -> (f64, f64) {
        let (mut sq, mut sum, mut n) = (0.0, 0.0, 0usize);
        for (rb, rv) in self.bands.iter().zip(&self.values) {
            for &p in &self.posts {
                let d = estimate(p, rb.azimuth) - f64::from(rv[p]);
                sq += d * d;
                sum += d;
                n += 1;
            }
        }
        ((sq / n as f64).sqrt(), sum / n as f64)
    }
}

/// RMS and largest absolute error of `svf(post)` against `reference` (one
/// value per post of `posts`, in order).
pub(super) fn svf_errors(
    posts: &[usize],
    reference: &[f64],
    svf: impl Fn(usize) -> f64,
) -> (f64, f64) {
    let (mut sq, mut max) = (0.0, 0f64);
    for (&p, r) in posts.iter().zip(reference) {
        let d = svf(p) - r;
        sq += d * d;
        max = max.max(d.abs());
    }
    ((sq / posts.len() as f64).sqrt(), max)
}

/// The horizon at `azimuth` of a post whose values at the ascending
/// `azimuths` are `at(i)`: linear between the two neighbours, as
/// `lit_fraction` does.
pub(super) fn interpolated(azimuths: &[f64], azimuth: f64, at: impl Fn(usize) -> f64) -> f64 {
    let (i, j, f) = bands_around(azimuths, azimuth);
    between(at(i), at(j), f)
}

/// Errors of `method` with `count` bands (line directions within
/// `tolerance` degrees of their nominal azimuths, or the default) against
/// `reference`, on the posts of the central half of `terrain`.
pub fn accuracy(
    terrain: &Terrain,
    reference: &Reference,
    method: Method,
    count: usize,
    tolerance: Option<f64>,
) -> AccuracyRow {
    let bands = plan_bands(method, count, terrain.dx, terrain.dy, tolerance);
    let (values, seconds, _) = all_bands(terrain, &bands, BandOptions::default());
    let azimuths: Vec<f64> = bands.iter().map(|b| b.azimuth).collect();
    let estimate = |post: usize, az: f64| -> f64 {
        match bands[0].kind {
            BandKind::Sector { count, .. } => {
                let i = (az / (360.0 / count as f64)).round() as usize % count;
                f64::from(values[i][post])
            }
            _ => interpolated(&azimuths, az, |i| f64::from(values[i][post])),
        }
    };
    let (horizon_rms_deg, horizon_bias_deg) = reference.horizon_errors(estimate);
    let integrals = integrals(&bands);
    let (svf_rms, svf_max) = svf_errors(&reference.posts, &reference.svf, |p| {
        svf_of(&integrals, &values, p)
    });
    AccuracyRow {
        method: method.name().into(),
        bands: count,
        direction_tolerance_deg: tolerance,
        seconds,
        horizon_rms_deg,
        horizon_bias_deg,
        svf_rms,
        svf_max,
    }
}

/// The accuracy study: on a centred `side x side` crop of `whole` (or all
/// of it when smaller), the reference with `reference` directions and every
/// method and count against it; with `line_tolerance`, the line method's
/// counts again with their directions that far from nominal.
#[derive(Debug, Serialize)]
pub struct AccuracyStudy {
    pub crop: usize,
    pub reference_directions: usize,
    pub reference_seconds: f64,
    pub rows: Vec<AccuracyRow>,
    /// The peers' outputs on the same crop, against the same reference.
    pub peers: Vec<PeerRow>,
}

/// The side of the study's centred crop: `side`, or all of a smaller DEM.
pub fn crop_side(whole: &Terrain, side: usize) -> usize {
    side.min(whole.width).min(whole.height)
}

pub fn accuracy_study(
    whole: &Terrain,
    side: usize,
    reference: usize,
    methods: &[Method],
    counts: &[usize],
    line_tolerance: Option<f64>,
    peers: &[LoadedPeer],
) -> AccuracyStudy {
    let side = crop_side(whole, side);
    let (x0, y0) = ((whole.width - side) / 2, (whole.height - side) / 2);
    let cropped: Vec<f32> = (y0..y0 + side)
        .flat_map(|r| whole.z[r * whole.width + x0..][..side].iter().copied())
        .collect();
    let small = Terrain::new(&cropped, side, side, whole.dx, whole.dy)
        .with_row_scale(whole.row_scale.crop(y0..y0 + side));
    let reference_bands = Reference::new(&small, reference);
    let tolerances = std::iter::once(None).chain(line_tolerance.map(Some));
    let rows = tolerances
        .flat_map(|t| methods.iter().map(move |&m| (m, t)))
        .flat_map(|(m, t)| counts.iter().map(move |&k| (m, k, t)))
        // Only lines have a tolerance, and the stage refuses one past
        // `tolerance_limit`.
        .filter(|&(m, k, t)| {
            t.is_none_or(|t| {
                m == Method::Line && t < terrabake::algorithms::horizon::line::tolerance_limit(k)
            })
        })
        .map(|(m, k, t)| accuracy(&small, &reference_bands, m, k, t))
        .collect();
    AccuracyStudy {
        crop: side,
        reference_directions: reference,
        reference_seconds: reference_bands.seconds,
        rows,
        peers: peers.iter().map(|p| p.score(&reference_bands)).collect(),
    }
}

/// The speed runs as a Markdown table.
pub fn speed_table_markdown(rows: &[SpeedRow]) -> String {
    markdown_table(
        &[
            "method",
            "bands",
            "posts",
            "time (s)",
            "post-bands / s",
            "work / post-band",
        ],
        rows.iter().map(|r| {
            vec![
                r.method.clone(),
                r.bands.to_string(),
                r.posts.to_string(),
                format!("{:.3}", r.seconds),
                format!("{:.3e}", r.post_bands_per_second),
                format!("{:.1}", r.work_per_post_band),
            ]
        }),
    )
}

/// The accuracy study as a Markdown table.
pub fn accuracy_table_markdown(rows: &[AccuracyRow]) -> String {
    markdown_table(
        &[
            "method",
            "bands",
            "time (s)",
            "horizon RMS error (deg)",
            "horizon bias (deg)",
            "svf RMS error",
            "svf max error",
        ],
        rows.iter().map(|r| {
            vec![
                r.label(),
                r.bands.to_string(),
                format!("{:.3}", r.seconds),
                format!("{:.3}", r.horizon_rms_deg),
                format!("{:+.3}", r.horizon_bias_deg),
                format!("{:.5}", r.svf_rms),
                format!("{:.4}", r.svf_max),
            ]
        }),
    )
}

/// `PREFIX_horizon.svg` and `PREFIX_svf.svg`: error against time, one line
/// per method through its band counts, a triangle per peer output.
pub fn accuracy_charts(prefix: &Path, study: &AccuracyStudy) -> Result<()> {
    let rows = &study.rows;
    let series = |value: &dyn Fn(&AccuracyRow) -> f64| -> Vec<Series> {
        let mut labels: Vec<String> = Vec::new();
        for r in rows {
            if !labels.contains(&r.label()) {
                labels.push(r.label());
            }
        }
        labels
            .into_iter()
            .map(|label| {
                let of = rows.iter().filter(|r| r.label() == label);
                let first = of.clone().next().expect("a label names a row");
                let counts = (
                    of.clone().map(|r| r.bands).min().unwrap_or(0),
                    of.clone().map(|r| r.bands).max().unwrap_or(0),
                );
                let counts = format!("{} .. {}", counts.0, counts.1);
                Series {
                    name: match (first.method.as_str(), first.direction_tolerance_deg) {
                        ("line", None) => format!("line (exact sight lines), K = {counts}"),
                        ("line", Some(t)) => {
                            format!("line, directions within {t} deg of nominal, K = {counts}")
                        }
                        ("sector", _) => format!("sector (Stewart's wedges), s = {counts}"),
                        _ => format!("sampled (centre line, nearest post), K = {counts}"),
                    },
                    points: of.clone().map(|r| (r.seconds, value(r))).collect(),
                    labels: of.map(|r| r.bands.to_string()).collect(),
                }
            })
            .collect()
    };
    // A peer's outputs under one name make one curve, through its knob.
    let marks = |value: &dyn Fn(&PeerRow) -> Option<f64>, label: &dyn Fn(&PeerRow) -> String| {
        let mut curves: Vec<(String, Vec<&PeerRow>)> = Vec::new();
        for p in study.peers.iter().filter(|p| value(p).is_some()) {
            match curves.iter_mut().find(|(name, _)| *name == label(p)) {
                Some((_, of)) => of.push(p),
                None => curves.push((label(p), vec![p])),
            }
        }
        curves
            .into_iter()
            .map(|(name, mut of)| {
                of.sort_by(|a, b| a.seconds.total_cmp(&b.seconds));
                let points = of.iter().map(|p| (p.seconds, value(p).unwrap_or(f64::NAN)));
                let series = Series::new(name, points.collect());
                if of.iter().all(|p| p.knob.is_some()) {
                    series.labelled(of.iter().filter_map(|p| p.knob.clone()).collect())
                } else {
                    series
                }
            })
            .collect::<Vec<_>>()
    };
    let path =
        |suffix: &str| std::path::PathBuf::from(format!("{}_{suffix}.svg", prefix.display()));
    log_log_svg_with_marks(
        &path("horizon"),
        "Horizon angle error against time (reference: 1024 exact sight lines)",
        "time for all bands (s, 2 cores)",
        "RMS horizon angle error (degrees)",
        &series(&|r| r.horizon_rms_deg),
        &marks(&|p| p.horizon_rms_deg, &|p| p.name.clone()),
    )?;
    log_log_svg_with_marks(
        &path("svf"),
        "Sky-view factor error against time (reference: 1024 exact sight lines)",
        "time for all bands (s, 2 cores)",
        "RMS sky-view factor error",
        &series(&|r| r.svf_rms),
        &marks(&|p| Some(p.svf_rms), &|p| match p.svf_definition {
            SvfDefinition::Zaksek => p.name.clone(),
            SvfDefinition::SlopeAware => format!("{} (slope-aware svf)", p.name),
        }),
    )
}

/// What `K` harmonics cost ([`terrabake::algorithms::horizon::fourier`]): the error of the
/// fit at the stored band azimuths over every post.
#[derive(Debug, Clone, Serialize)]
pub struct FourierRow {
    pub harmonics: usize,
    pub coefficients: usize,
    /// RMS over every post and band, degrees.
    pub rms_deg: f64,
    /// The 99th percentile over posts of a post's largest band error.
    pub p99_deg: f64,
    pub max_deg: f64,
}

/// The Fourier study of a horizon layer's `bands` (band-major) at
/// `azimuths`, one row per harmonics count.
pub fn fourier_study(
    bands: &[Vec<f32>],
    azimuths: &[f64],
    harmonics: &[usize],
) -> Result<Vec<FourierRow>> {
    let posts = bands.first().map_or(0, Vec::len);
    harmonics
        .iter()
        .map(|&k| {
            let fit = terrabake::algorithms::horizon::fourier::FourierBasis::new(azimuths, k)?;
            // Per post: its sum of squares and its largest error.
            let per_post: Vec<(f64, f64, usize)> = (0..posts)
                .into_par_iter()
                .map_init(
                    || {
                        let n = bands.len();
                        (vec![0f32; n], vec![0f32; fit.len()], vec![0f64; n])
                    },
                    |(post, c, back), i| {
                        post.iter_mut().zip(bands).for_each(|(p, b)| *p = b[i]);
                        if post.iter().any(|v| v.is_nan()) {
                            return (0.0, 0.0, 0);
                        }
                        fit.fit(post, c);
                        fit.reconstruct(c, back);
                        back.iter().zip(post.iter()).fold(
                            (0.0, 0.0, bands.len()),
                            |(sq, worst, n), (&b, &h)| {
                                let e = (b - f64::from(h)).abs();
                                (sq + e * e, f64::max(worst, e), n)
                            },
                        )
                    },
                )
                .collect();
            let n: usize = per_post.iter().map(|p| p.2).sum();
            let sq: f64 = per_post.iter().map(|p| p.0).sum();
            let mut worst: Vec<f64> = per_post.iter().filter(|p| p.2 > 0).map(|p| p.1).collect();
            worst.sort_by(f64::total_cmp);
            let p99 = worst
                .get(((worst.len() as f64 * 0.99) as usize).min(worst.len().saturating_sub(1)))
                .copied()
                .unwrap_or(0.0);
            Ok(FourierRow {
                harmonics: k,
                coefficients: fit.len(),
                rms_deg: (sq / n.max(1) as f64).sqrt(),
                p99_deg: p99,
                max_deg: worst.last().copied().unwrap_or(0.0),
            })
        })
        .collect()
}

/// The study as a Markdown table.
pub fn fourier_table_markdown(rows: &[FourierRow], bands: usize) -> String {
    markdown_table(
        &[
            "harmonics K",
            "coefficients 2K + 1",
            "share of the bands",
            "RMS error (deg)",
            "p99 of each post's largest (deg)",
            "largest (deg)",
        ],
        rows.iter().map(|r| {
            vec![
                r.harmonics.to_string(),
                r.coefficients.to_string(),
                format!("{:.2}", r.coefficients as f64 / bands as f64),
                format!("{:.3}", r.rms_deg),
                format!("{:.3}", r.p99_deg),
                format!("{:.2}", r.max_deg),
            ]
        }),
    )
}

/// `terrabake-bench horizons`: its flags.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchHorizonsArgs {
    /// The asset to measure (an ingested DEM).
    pub asset: std::path::PathBuf,
    /// Band counts for the accuracy study, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "8,16,32,64,128,256")]
    pub counts: Vec<usize>,
    /// Methods for the accuracy study, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "line,sector,sampled", value_parser = terrabake::stage::args::named(&Method::ALL, Method::name))]
    pub methods: Vec<Method>,
    /// Directions of the reference.
    #[arg(long, default_value_t = 1024)]
    pub reference: usize,
    /// Side of the centred crop for the accuracy study, posts.
    #[arg(long, default_value_t = 256)]
    pub crop: usize,
    /// The line method's counts again with their directions this far (degrees) from i * 360 /
    /// count: what a wider `horizons --direction-tolerance` costs in accuracy (default: only the
    /// stage's default, an eighth of the spacing).
    #[arg(long, value_name = "DEG")]
    pub direction_tolerance: Option<f64>,
    /// Whole-DEM speed runs METHOD:COUNT, comma-separated (none: skip).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "line:16,line:64,sector:16,sector:64,sampled:16"
    )]
    pub speed: Vec<String>,
    /// Write PREFIX_horizon.svg and PREFIX_svf.svg (with --fourier, PREFIX_fourier.svg).
    #[arg(long)]
    pub chart: Option<std::path::PathBuf>,
    /// Instead of the study above: the asset's stored horizon layer fitted with these numbers of
    /// Fourier harmonics (comma-separated; at most (bands - 1) / 2), the error at its band
    /// azimuths against the coefficients kept.
    #[arg(long, value_delimiter = ',')]
    pub fourier: Vec<usize>,
    /// Score other tools' outputs too: the `peers.json` that `make bench-peers` writes (its
    /// outputs on the same crop, in our conventions); they join the tables and the charts.
    #[arg(long, value_name = "PEERS_JSON")]
    pub peers: Option<std::path::PathBuf>,
    /// Print the rows as JSON.
    #[arg(long)]
    pub json: bool,
}

impl BenchHorizonsArgs {
    /// Runs the study and prints its tables (or JSON); `say` reports files.
    pub fn run(&self, say: &dyn Fn(String)) -> Result<()> {
        use anyhow::Context;
        let opened = terrabake::stage::asset::open(&self.asset)?;
        if !self.fourier.is_empty() {
            let (bands, azimuths) = terrabake::stages::horizons::read_horizons(&opened)?;
            let rows = fourier_study(&bands, &azimuths, &self.fourier)?;
            if self.json {
                println!("{}", serde_json::to_string_pretty(&rows)?);
            } else {
                print!("{}", fourier_table_markdown(&rows, bands.len()));
            }
            if let Some(prefix) = &self.chart {
                let path = std::path::PathBuf::from(format!("{}_fourier.svg", prefix.display()));
                let series = |name: &str, f: &dyn Fn(&FourierRow) -> f64| {
                    Series::new(
                        name,
                        rows.iter().map(|r| (r.coefficients as f64, f(r))).collect(),
                    )
                };
                log_log_svg(
                    &path,
                    &format!(
                        "Horizons as Fourier coefficients ({} stored bands)",
                        bands.len()
                    ),
                    "coefficients per post (2K + 1)",
                    "error at the band azimuths (degrees)",
                    &[
                        series("RMS", &|r| r.rms_deg),
                        series("p99 of each post's largest", &|r| r.p99_deg),
                        series("largest", &|r| r.max_deg),
                    ],
                )?;
                say(format!("wrote {}", path.display()));
            }
            return Ok(());
        }
        if let Some(t) = self.direction_tolerance {
            anyhow::ensure!(
                t > 0.0 && t.is_finite(),
                "--direction-tolerance {t}: give a positive number of degrees"
            );
        }
        let dem = terrabake::terrain::held::HeldDem::read(&opened)?;
        let whole = dem.terrain(0.0);
        let (manifest, peers) = match &self.peers {
            Some(path) => {
                let m = PeerManifest::read(path)?;
                let dir = path.parent().unwrap_or(Path::new("."));
                let peers = m
                    .load(dir, crop_side(&whole, self.crop))
                    .with_context(|| path.display().to_string())?;
                (Some(m), peers)
            }
            None => (None, Vec::new()),
        };
        let runs = self
            .speed
            .iter()
            .filter(|r| r.as_str() != "none")
            .map(|r| {
                let (m, k) = r.split_once(':').context("--speed takes METHOD:COUNT")?;
                let m = m
                    .parse::<Method>()
                    .map_err(|e| anyhow::anyhow!("--speed {r}: {e}"))?;
                Ok((m, k.parse::<usize>().context("--speed METHOD:COUNT")?))
            })
            .collect::<Result<Vec<_>>>()?;
        let speed_rows = speed(&whole, &runs);
        let study = accuracy_study(
            &whole,
            self.crop,
            self.reference,
            &self.methods,
            &self.counts,
            self.direction_tolerance,
            &peers,
        );
        if self.json {
            println!(
                "{}",
                serde_json::to_string_pretty(&serde_json::json!({
                    "speed": speed_rows,
                    "crop": study.crop,
                    "reference_directions": study.reference_directions,
                    "reference_seconds": study.reference_seconds,
                    "accuracy": study.rows,
                    "peers": study.peers,
                }))?
            );
        } else {
            if !speed_rows.is_empty() {
                print!("{}", speed_table_markdown(&speed_rows));
                println!();
            }
            println!(
                "accuracy on a {side} x {side} crop, reference {} directions ({:.1} s):",
                self.reference,
                study.reference_seconds,
                side = study.crop
            );
            print!("{}", accuracy_table_markdown(&study.rows));
            if let Some(m) = &manifest {
                println!();
                println!("the peers on the same crop, {} directions:", m.directions);
                print!("{}", super::peers::accuracy_table_markdown(&study.peers));
                println!();
                println!("whole processes on the whole DEM ({}):", m.dem);
                print!("{}", super::peers::whole_table_markdown(m)?);
                println!();
                print!("{}", super::peers::notes_markdown(m));
            }
        }
        if let Some(prefix) = &self.chart {
            accuracy_charts(prefix, &study)?;
            say(format!(
                "wrote {0}_horizon.svg and {0}_svf.svg",
                prefix.display()
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrabake::io::synth::{height, SynthKind};

    /// With a tolerance, the line method's counts come again with it where
    /// it is under half their spacing, and no other method's.
    #[test]
    fn a_wider_tolerance_adds_line_rows_only_where_the_stage_allows_it() {
        let side = 40;
        let z: Vec<f32> = (0..side * side)
            .map(|i| {
                let (x, y) = ((i % side) as u32, (i / side) as u32);
                height(SynthKind::Fractal, x, y, side as u32, side as u32, 7) * 100.0
            })
            .collect();
        let t = Terrain::new(&z, side, side, 30.0, 30.0);
        let study = accuracy_study(
            &t,
            side,
            64,
            &[Method::Line, Method::Sector],
            &[8, 16, 64],
            Some(4.5),
            &[],
        );
        let labels: Vec<(String, usize)> =
            study.rows.iter().map(|r| (r.label(), r.bands)).collect();
        let within = |k| ("line within 4.5 deg".to_string(), k);
        assert!(
            labels.contains(&within(8)) && labels.contains(&within(16)),
            "{labels:?}"
        );
        assert!(
            !labels.contains(&within(64)),
            "64 directions are 5.6 deg apart: {labels:?}"
        );
        assert!(
            !labels.iter().any(|(l, _)| l.starts_with("sector within")),
            "{labels:?}"
        );
        assert_eq!(labels.len(), 2 * 3 + 2);
        for r in &study.rows {
            assert!(
                r.horizon_rms_deg.is_finite() && r.svf_rms.is_finite(),
                "{r:?}"
            );
        }
    }
}
