//! `terrabake profile`: the horizon around one point at any azimuth step,
//! from the exact sight line at that azimuth (not interpolated between the
//! stored bands), with the distance to the point that sets it: what PV
//! far-shading tools (PVGIS, PVsyst, pvlib) take as a horizon profile.
//!
//! Each azimuth's horizon is [`brute::ray_horizon_records`]: the straight
//! line from the post over the two-triangle surface, every crossing with a
//! grid line or cell diagonal sampled, to the DEM's edge, with the earth's
//! curvature and refraction as the horizons stage has them. O(length of the
//! line) per azimuth, so a 1-degree profile of a 10^4-post DEM is 360
//! walks of at most 10^4 steps: milliseconds.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use serde::Serialize;

use crate::algorithms::horizon::brute;
use crate::error::bail;
use crate::stage::session::{Run, Session};
use crate::stage::sight::SightLines;
use crate::stages::viewshed::{post_at, Crs};
use crate::terrain::held::HeldDem;

/// How the profile is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ProfileFormat {
    /// `azimuth_deg,horizon_deg,distance_m`, compass azimuths (clockwise from north).
    Csv,
    /// The point, its post, the conventions and every azimuth's horizon and distance.
    Json,
    /// PVGIS's horizon columns `A_hor H_hor`: azimuth from south, west positive
    /// (-180 = north, -90 = east, 0 = south, 90 = west), then the horizon height; the
    /// first line a comment.
    Pvgis,
}

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  terrabake profile out/srtm.tbake --at -5.5,7.5 --crs lonlat\n  \
terrabake profile out/srtm.tbake --at 600,600 --crs grid --step 7.5 --format pvgis -o horizon.txt\n\n\
An azimuth whose line leaves the DEM without meeting terrain above -90 degrees (at the DEM's edge, \
looking out) has horizon -90 and no distance."
)]
pub struct ProfileArgs {
    /// The asset whose heights are read (its `height` layer).
    pub asset: PathBuf,
    /// The point, X,Y in --crs; the nearest post is used.
    #[arg(long, value_parser = crate::stage::args::parse_xy, allow_hyphen_values = true)]
    pub at: (f64, f64),
    /// The coordinates of --at: native (the DEM's CRS), lonlat, grid (column,row).
    #[arg(long, value_enum, default_value = "native")]
    pub crs: Crs,
    /// Degrees between azimuths (0.01 to 360), from north (0) clockwise.
    #[arg(long, default_value_t = 1.0, value_parser = crate::stage::args::parse_profile_step)]
    pub step: f64,
    /// csv, json or pvgis.
    #[arg(long, value_enum, default_value = "csv")]
    pub format: ProfileFormat,
    /// How far the horizon is looked for and how the Earth bends the sight lines.
    #[command(flatten)]
    pub sight: SightLines,
    /// Write here instead of standard output (atomically).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
}

/// One azimuth of a profile.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ProfilePoint {
    /// Compass degrees, clockwise from north.
    pub azimuth_deg: f64,
    /// Degrees above the horizontal; -90 when no terrain lies ahead.
    pub horizon_deg: f32,
    /// Horizontal metres to the point that sets the horizon.
    pub distance_m: Option<f64>,
}

/// `profile --format json`.
#[derive(Debug, Serialize)]
pub struct Profile {
    pub post: (usize, usize),
    pub height_m: f32,
    pub curvature: f64,
    pub azimuth_convention: &'static str,
    pub method: &'static str,
    pub points: Vec<ProfilePoint>,
}

/// The horizon at azimuths `0, step, ...` below 360 from `post`, looked
/// for no farther than `max_distance` metres where given.
pub fn profile(
    dem: &HeldDem,
    curvature: f64,
    max_distance: Option<f64>,
    post: (usize, usize),
    step: f64,
) -> crate::Result<Vec<ProfilePoint>> {
    if !(0.01..=360.0).contains(&step) {
        bail!("--step {step}: give 0.01 to 360 degrees (at most 36000 azimuths)");
    }
    let terrain = dem.terrain(curvature);
    let n = (360.0 / step - 1e-9).ceil() as usize;
    Ok((0..n)
        .map(|i| {
            let azimuth_deg = i as f64 * step;
            let records = brute::ray_horizon_records(&terrain, post, azimuth_deg);
            let within = brute::records_within(&records, max_distance);
            let last = within.last();
            ProfilePoint {
                azimuth_deg,
                horizon_deg: last.map_or(-90.0, |r| r.angle),
                distance_m: last.map(|r| r.distance),
            }
        })
        .collect())
}

/// One point's profile: the post nearest it, its height, the curvature
/// coefficient taken, and every azimuth's horizon.
#[derive(Debug, Clone)]
pub struct PointProfile {
    pub post: (usize, usize),
    pub height_m: f32,
    pub curvature: f64,
    pub points: Vec<ProfilePoint>,
}

/// The profile of each of `points` (X,Y in `crs`) of the asset's heights,
/// as `terrabake profile` computes one, the DEM read once and the points
/// in parallel: what the command and Python's `terrabake.profile` call.
pub fn profiles(
    asset: &terrabake_format::Asset<terrabake_format::Mmap>,
    points: &[(f64, f64)],
    crs: Crs,
    step: f64,
    sight: &SightLines,
) -> crate::Result<Vec<PointProfile>> {
    use rayon::prelude::*;
    let m = asset.manifest();
    sight.check()?;
    let dem = HeldDem::read(asset)?;
    let curvature = sight.curvature_coefficient(m);
    points
        .par_iter()
        .map(|&at| {
            let post = post_at(m, &dem, "--at", at, crs)?;
            Ok(PointProfile {
                post,
                height_m: dem.z()[post.1 * dem.width + post.0],
                curvature,
                points: profile(&dem, curvature, sight.max_distance, post, step)?,
            })
        })
        .collect()
}

impl Run for ProfileArgs {
    fn run(&self, _: &Session) -> crate::Result<ExitCode> {
        let asset = crate::stage::asset::open(&self.asset)?;
        let m = asset.manifest();
        let PointProfile {
            post,
            height_m,
            curvature,
            points,
        } = profiles(&asset, &[self.at], self.crs, self.step, &self.sight)?
            .pop()
            .expect("one point, one profile");
        let text = match self.format {
            ProfileFormat::Csv => {
                let mut t = String::from("azimuth_deg,horizon_deg,distance_m\n");
                for p in &points {
                    let d = p.distance_m.map_or(String::new(), |d| format!("{d:.1}"));
                    t += &format!("{},{:.4},{d}\n", p.azimuth_deg, p.horizon_deg);
                }
                t
            }
            ProfileFormat::Json => {
                let profile = Profile {
                    post,
                    height_m,
                    curvature,
                    azimuth_convention: "compass: degrees clockwise from north",
                    method: "exact sight line on the two-triangle surface at each azimuth",
                    points,
                };
                serde_json::to_string_pretty(&profile)? + "\n"
            }
            ProfileFormat::Pvgis => {
                let mut rows: Vec<(f64, f32)> = points
                    .iter()
                    .map(|p| (p.azimuth_deg - 180.0, p.horizon_deg))
                    .collect();
                rows.sort_by(|a, b| a.0.total_cmp(&b.0));
                // Where the point is, as PV tools are given it: longitude
                // and latitude on a geographic grid, else the DEM's CRS.
                let at = match &m.georef {
                    Some(g) => {
                        let (x, y) = g.post_to_world(post.0 as f64, post.1 as f64);
                        match (g.crs_kind, g.epsg) {
                            (terrabake_format::manifest::CrsKind::Geographic, _) => {
                                format!("longitude {x:.6}, latitude {y:.6}")
                            }
                            (_, Some(epsg)) => format!("x {x:.2}, y {y:.2} (EPSG:{epsg})"),
                            (_, None) => format!("x {x:.2}, y {y:.2}"),
                        }
                    }
                    None => format!("post {},{}", post.0, post.1),
                };
                let mut t = format!(
                    "# terrabake horizon at {at}: A_hor from south (west positive), H_hor degrees\n"
                );
                for (a, h) in rows {
                    t += &format!("{a} {h:.2}\n");
                }
                t
            }
        };
        match &self.output {
            Some(path) => crate::plumbing::output::write_atomically(path, |f| {
                Ok(f.write_all(text.as_bytes())?)
            }),
            None => std::io::stdout()
                .write_all(text.as_bytes())
                .map_err(Into::into),
        }?;
        Ok(ExitCode::SUCCESS)
    }
}
