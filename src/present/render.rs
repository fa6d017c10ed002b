//! Perspective views of an asset, traced with any method: Lambert shading
//! from the sun, sun shadows from shadow rays, a hypsometric tint, and a sky.
//! Used by `terrabake render` and by the tracing benchmark (Paglieroni and
//! Petersen's Table 1: 16 oblique views from inside the bounding box).
//!
//! Coordinates are local metres: `x` east and `y` north from the DEM's
//! south-west post, `z` the heights' metres (see `terrabake_format::trace`).

use rayon::prelude::*;
use serde::Serialize;
use std::process::ExitCode;
use terrabake_format::trace::{Counters, Method, Ray, Tracer};
use terrabake_format::{Asset, Mmap};

use crate::present::image::{write_png, Image};
use crate::stage::session::{Run, Session};
use crate::terrain::sun::Sun;
use crate::views::{builtin_views, normalize, Camera};

#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct RenderStats {
    pub pixels: u64,
    pub primary_rays: u64,
    pub primary_hits: u64,
    pub shadow_rays: u64,
    pub seconds: f64,
    /// Primary and shadow rays per second, over all threads.
    pub rays_per_second: f64,
    pub threads: usize,
    /// Means over primary rays.
    pub mean_steps: f64,
    pub mean_cells: f64,
    pub mean_nodes_pushed: f64,
}

/// What to render.
#[derive(Debug, Clone, Copy)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    pub method: Method,
    pub sun: Sun,
    /// Trace only every `every`-th pixel in x and y (1: all); the rest are
    /// filled from the traced ones, for quick previews and the benchmark.
    pub every: u32,
    /// Sun shadows: shadow rays, the stored horizons, or none (benchmarks
    /// of primary rays alone).
    pub shadows: Shadows,
    /// Vertical exaggeration of the terrain (1: true heights). The camera
    /// and look-at heights are in exaggerated metres.
    pub exaggeration: f64,
    /// Shading normals: smooth across cells, or each triangle's own.
    pub normals: Normals,
}

/// The normals that shading uses. Hits and shadows are of the triangles
/// either way; only the light on them differs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Normals {
    /// Post normals by central differences, bilinear across each cell
    /// (`surface::smooth_normal`): no facets.
    Smooth,
    /// The normal of the triangle hit: every facet shows.
    Flat,
}

/// The smooth normal (unit, true heights) at `hit`, from the 4 x 4 posts
/// around its cell; posts outside the DEM are missing.
fn smooth_normal_at<D: AsRef<[u8]>>(
    height: &terrabake_format::Layer<D>,
    hit: &terrabake_format::trace::Hit,
    cell: (f64, f64),
    rows_max: f64,
) -> terrabake_format::Result<[f64; 3]> {
    let (c, r) = hit.cell;
    let (x0, y0) = (c.saturating_sub(1), r.saturating_sub(1));
    let (x1, y1) = ((c + 3).min(height.width()), (r + 3).min(height.height()));
    let mut window = [0f32; 16];
    height.read_window(
        0,
        x0,
        y0,
        x1 - x0,
        y1 - y0,
        &mut window[..((x1 - x0) * (y1 - y0)) as usize],
    )?;
    let mut posts = [f32::NAN; 16];
    for y in y0..y1 {
        for x in x0..x1 {
            let at = ((y - y0) * (x1 - x0) + (x - x0)) as usize;
            posts[((y + 1 - r) * 4 + (x + 1 - c)) as usize] = window[at];
        }
    }
    let east = hit.point[0] / cell.0 - f64::from(c);
    let north = f64::from(r) + 1.0 - (rows_max - hit.point[1] / cell.1);
    Ok(normalize(terrabake_format::surface::smooth_normal(
        &posts, east, north, cell.0, cell.1,
    )))
}

/// Where sun shadows come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shadows {
    Off,
    /// A shadow ray from every lit hit towards the sun (exact).
    Rays,
    /// The horizons stage's angles: the share of the sun's disc above the
    /// horizon (`lit_fraction`, radius 0.27 degrees), bilinear between the
    /// four posts around the hit. No ray; soft edges. Under an exaggeration
    /// `e` the sun stands where it does over the exaggerated surface: at
    /// `atan(tan(elevation) / e)` over the true one.
    Horizons,
}

/// The lit share of the sun's disc at fractional post `(col, row)`:
/// `lit_fraction` of the four posts around it, bilinear (nodata posts left
/// out).
fn lit_between_posts<D: AsRef<[u8]>>(
    map: &terrabake_format::horizons::HorizonMap<'_, D>,
    (col, row): (f64, f64),
    sun: Sun,
) -> terrabake_format::Result<f64> {
    let (c0, r0) = (col.floor().max(0.0), row.floor().max(0.0));
    let (fc, fr) = ((col - c0).clamp(0.0, 1.0), (row - r0).clamp(0.0, 1.0));
    let (mut sum, mut weight) = (0.0, 0.0);
    for (dc, dr, w) in [
        (0.0, 0.0, (1.0 - fc) * (1.0 - fr)),
        (1.0, 0.0, fc * (1.0 - fr)),
        (0.0, 1.0, (1.0 - fc) * fr),
        (1.0, 1.0, fc * fr),
    ] {
        let (c, r) = ((c0 + dc) as u32, (r0 + dr) as u32);
        if w > 0.0 {
            if let Ok(Some(lit)) = map.lit_fraction(c, r, sun.azimuth, sun.elevation, 0.27) {
                sum += w * lit;
                weight += w;
            }
        }
    }
    Ok(if weight > 0.0 { sum / weight } else { 1.0 })
}

/// Renders `camera`'s view. Errors only when the asset cannot be read.
pub fn render(
    asset: &Asset<Mmap>,
    tracer: &Tracer<'_, Mmap>,
    camera: &Camera,
    opts: &RenderOptions,
) -> crate::Result<(Image, RenderStats)> {
    crate::error::ensure!(
        camera.eye != camera.look_at,
        "the camera looks at its own position {:?}: give a --look-at point away from --camera",
        camera.eye
    );
    let (w, h, every) = (opts.width, opts.height, opts.every.max(1));
    // The traced pixels and the image, 3 bytes each.
    crate::plumbing::resources::ensure_memory(
        u64::from(w) * u64::from(h) * 6,
        &format!("a {w} x {h} image"),
    )?;
    let range = asset
        .manifest()
        .height_range
        .map_or((0.0, 1.0), |r| (f64::from(r.min), f64::from(r.max)));
    let sun = opts.sun.direction();
    let e = if opts.exaggeration > 0.0 {
        opts.exaggeration
    } else {
        1.0
    };
    // Shading and shadows are of the same, exaggerated surface: towards
    // the sun over it is, over the true heights, a ray whose rise is
    // divided by e (and a sun that much lower).
    let sun_true = Sun {
        azimuth: opts.sun.azimuth,
        elevation: (opts.sun.elevation.to_radians().tan() / e)
            .atan()
            .to_degrees(),
    };
    let horizons = match opts.shadows {
        Shadows::Horizons => Some(terrabake_format::horizons::HorizonMap::open(asset).map_err(
            |e| {
                anyhow::anyhow!(
                    "{e}: horizon shadows need the horizons stage (terrabake horizons {})",
                    asset.dir().display()
                )
            },
        )?),
        _ => None,
    };
    let m = asset.manifest();
    let shading = Shading {
        tracer,
        opts,
        height: asset.height()?,
        cell: (m.cell_size.dx, m.cell_size.dy),
        rows_max: f64::from(m.height - 1),
        range,
        sun,
        sun_true,
        e,
        horizons,
    };
    let start = std::time::Instant::now();
    let projector = camera.projector(w, h);
    let traced_rows: Vec<u32> = (0..h).step_by(every as usize).collect();
    let rows: Vec<anyhow::Result<TracedRow>> = traced_rows
        .par_iter()
        .map(|&py| {
            let mut row = TracedRow {
                pixels: Vec::with_capacity(w.div_ceil(every) as usize),
                counters: Counters::default(),
                hits: 0,
                shadow_rays: 0,
            };
            for px in (0..w).step_by(every as usize) {
                let ray = projector.ray(f64::from(px), f64::from(py));
                let colour = shading.pixel(&ray, &mut row)?;
                row.pixels.push(colour);
            }
            Ok(row)
        })
        .collect();
    let seconds = start.elapsed().as_secs_f64();
    let mut stats = RenderStats {
        threads: rayon::current_num_threads(),
        seconds,
        ..Default::default()
    };
    let mut totals = Counters::default();
    let mut traced: Vec<Vec<[u8; 3]>> = Vec::with_capacity(rows.len());
    for row in rows {
        let TracedRow {
            pixels: row,
            counters: c,
            hits,
            shadow_rays: shadows,
        } = row?;
        stats.primary_rays += row.len() as u64;
        stats.primary_hits += hits;
        stats.shadow_rays += shadows;
        totals += c;
        traced.push(row);
    }
    stats.pixels = u64::from(w) * u64::from(h);
    let n = stats.primary_rays.max(1) as f64;
    stats.mean_steps = totals.steps as f64 / n;
    stats.mean_cells = totals.cells as f64 / n;
    stats.mean_nodes_pushed = totals.nodes_pushed as f64 / n;
    stats.rays_per_second = (stats.primary_rays + stats.shadow_rays) as f64 / seconds.max(1e-9);
    // Untraced pixels take the nearest traced one up and to the left.
    let mut rgb = Vec::with_capacity(w as usize * h as usize * 3);
    for py in 0..h {
        let row = &traced[(py / every) as usize];
        for px in 0..w {
            rgb.extend_from_slice(&row[(px / every) as usize]);
        }
    }
    Ok((
        Image {
            width: w,
            height: h,
            rgb,
        },
        stats,
    ))
}

/// What colouring a pixel needs, the same for every pixel of a view.
struct Shading<'a> {
    tracer: &'a Tracer<'a, Mmap>,
    opts: &'a RenderOptions,
    height: &'a terrabake_format::Layer<Mmap>,
    cell: (f64, f64),
    rows_max: f64,
    /// The heights' range, for the hypsometric tint.
    range: (f64, f64),
    /// Unit vector towards the sun over the exaggerated surface.
    sun: [f64; 3],
    /// The sun over the true heights (lower by the exaggeration).
    sun_true: Sun,
    e: f64,
    horizons: Option<terrabake_format::horizons::HorizonMap<'a, Mmap>>,
}

impl Shading<'_> {
    /// The colour of the pixel whose ray is `ray`; what it cost goes into
    /// `row`.
    fn pixel(&self, ray: &Ray, row: &mut TracedRow) -> anyhow::Result<[u8; 3]> {
        let (opts, e) = (self.opts, self.e);
        // Exaggerating the terrain by e is tracing the ray with its z
        // divided by e: the hit's t is the same.
        let (hit, c) = self.tracer.trace(&squash(ray, e), opts.method)?;
        row.counters += c;
        let Some(hit) = hit else {
            return Ok(sky(ray));
        };
        row.hits += 1;
        let n = match opts.normals {
            Normals::Flat => hit.normal.map(f64::from),
            Normals::Smooth => smooth_normal_at(self.height, &hit, self.cell, self.rows_max)?,
        };
        let n = normalize([n[0] * e, n[1] * e, n[2]]);
        let sun = self.sun;
        let lambert = (n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2]).max(0.0);
        let lit = if lambert <= 0.0 {
            0.0
        } else {
            match (opts.shadows, &self.horizons) {
                (Shadows::Rays, _) => {
                    row.shadow_rays += 1;
                    // Start just above the hit so the ray leaves its own triangle.
                    let lift = 1e-3 * (self.range.1 - self.range.0).max(1.0);
                    let origin = [hit.point[0], hit.point[1], hit.point[2] + lift];
                    let shadow = Ray {
                        origin,
                        dir: self.sun_true.direction(),
                        t_min: 0.0,
                        t_max: f64::INFINITY,
                    };
                    if self.tracer.trace(&shadow, opts.method)?.0.is_none() {
                        1.0
                    } else {
                        0.0
                    }
                }
                (Shadows::Horizons, Some(map)) => {
                    let (col, row) = (
                        hit.point[0] / self.cell.0,
                        self.rows_max - hit.point[1] / self.cell.1,
                    );
                    lit_between_posts(map, (col, row), self.sun_true)?
                }
                _ => 1.0,
            }
        };
        let (lo, hi) = self.range;
        let t = ((hit.point[2] - lo) / (hi - lo).max(1e-9)) as f32;
        let tint = crate::present::legend::hypsometric(t);
        let light = 0.25 + 0.75 * (lit * lambert) as f32;
        Ok(tint.map(|c| (c * light).clamp(0.0, 255.0) as u8))
    }
}

/// One traced row of pixels and what it cost.
struct TracedRow {
    pixels: Vec<[u8; 3]>,
    counters: Counters,
    hits: u64,
    shadow_rays: u64,
}

/// The ray in true heights for a terrain exaggerated `e` times.
fn squash(ray: &Ray, e: f64) -> Ray {
    let mut r = *ray;
    r.origin[2] /= e;
    r.dir[2] /= e;
    r
}

fn sky(ray: &Ray) -> [u8; 3] {
    let d = normalize(ray.dir);
    let t = d[2].clamp(-0.2, 1.0) as f32;
    [
        (170.0 - 90.0 * t) as u8,
        (200.0 - 70.0 * t) as u8,
        (235.0 - 20.0 * t) as u8,
    ]
}

/// Refuses `method` on an asset without the layers it walks, naming the
/// asset and the command that adds them.
pub(crate) fn require_layers(
    tracer: &Tracer<'_, Mmap>,
    method: Method,
    asset: &std::path::Path,
) -> anyhow::Result<()> {
    let missing = match method {
        Method::Hierarchical if !tracer.has_pyramid() => Some(("the max pyramid", "pyramid")),
        Method::Parametric if !tracer.has_cones() => Some(("the cone planes", "cones")),
        _ => None,
    };
    match missing {
        Some((what, command)) => crate::error::bail!(
            "{0}: --method {1} needs {what}, which this asset does not have: run `terrabake {command} {0}` first, or choose --method incremental",
            asset.display(),
            method.name()
        ),
        None => Ok(()),
    }
}

/// `terrabake render`: a perspective view traced through an asset, or an
/// overhead map shaded from its horizons (`--shade`).
#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// The asset directory (made by `terrabake ingest` or `terrabake bake`).
    pub asset: std::path::PathBuf,
    /// Instead of a perspective view: an overhead map shaded from the stored horizons alone,
    /// `sky` (overcast sky, radiosity) or `sun:AZ,EL` (sun disc and Stewart's sky); needs the
    /// horizons stage.
    #[arg(long, conflicts_with_all = ["view", "camera"])]
    pub shade: Option<crate::present::shade::Shade>,
    /// Camera position X,Y,Z (local metres).
    #[arg(long, value_parser = crate::stage::args::parse_point, allow_hyphen_values = true, requires = "look_at", conflicts_with = "view")]
    pub camera: Option<[f64; 3]>,
    /// Point the camera looks at, X,Y,Z (local metres).
    #[arg(long, value_parser = crate::stage::args::parse_point, allow_hyphen_values = true, requires = "camera")]
    pub look_at: Option<[f64; 3]>,
    /// One of the sixteen built-in oblique views (1..=16).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub view: Option<u32>,
    /// Horizontal field of view, degrees (built-in views use 104).
    #[arg(long, allow_hyphen_values = true, value_parser = crate::stage::args::parse_fov)]
    pub fov: Option<f64>,
    /// Image size WIDTHxHEIGHT.
    #[arg(long, value_parser = crate::stage::args::parse_size, default_value = "800x600")]
    pub size: (u32, u32),
    /// Tracer: incremental, runs, hierarchical, parametric, brute-force (all give the same picture;
    /// hierarchical needs the pyramid stage, parametric the cones stage).
    #[arg(long, default_value = "hierarchical")]
    pub method: Method,
    /// Sun azimuth (clockwise from north) and elevation, degrees.
    #[arg(long, value_parser = crate::stage::args::parse_sun, default_value = "135,35")]
    pub sun: Sun,
    /// Trace every N-th pixel only (others copy the nearest traced one).
    #[arg(long, default_value_t = 1)]
    pub every: u32,
    /// No shadow rays.
    #[arg(long)]
    pub no_shadows: bool,
    /// Sun shadows from the stored horizons (lit_fraction, soft, no shadow rays; needs the
    /// horizons stage) instead of shadow rays.
    #[arg(long, conflicts_with = "no_shadows")]
    pub horizon_shadows: bool,
    /// Vertical exaggeration (camera heights are then in exaggerated metres).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true, value_parser = crate::stage::args::parse_positive)]
    pub exaggerate: f64,
    /// Shading normals: smooth (post normals interpolated across cells) or flat (each
    /// triangle's own, facets showing). Hits and shadows are exact either way.
    #[arg(long, value_enum, default_value = "smooth")]
    pub normals: crate::present::render::Normals,
    /// The PNG to write (its directory is created).
    #[arg(short, long)]
    pub output: std::path::PathBuf,
    /// Print rays per second and mean steps per ray.
    #[arg(long)]
    pub stats: bool,
    /// Print the statistics as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `terrabake render`: an overhead map shaded from the horizons, or a
/// perspective view traced through the asset.
impl Run for RenderArgs {
    /// Renders and writes the PNG.
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let a = self;
        let opened = crate::stage::asset::open(&a.asset)?;
        if let Some(shade) = a.shade {
            crate::present::shade::write_shade_png(&opened, shade, &a.output, 4096)?;
            s.say(format!("wrote {}", a.output.display()));
            return Ok(ExitCode::SUCCESS);
        }
        let tracer = Tracer::new(&opened)?;
        crate::present::render::require_layers(&tracer, a.method, &a.asset)?;
        let mut cam = match (a.view, a.camera, a.look_at) {
            (Some(v), _, _) => builtin_views(&tracer, &opened)[v as usize - 1],
            (None, Some(eye), Some(look_at)) => Camera {
                eye,
                look_at,
                fov: 60.0,
            },
            _ => crate::error::bail!("give --view N, or --camera X,Y,Z and --look-at X,Y,Z"),
        };
        cam.fov = a.fov.unwrap_or(cam.fov);
        let opts = RenderOptions {
            width: a.size.0,
            height: a.size.1,
            method: a.method,
            sun: a.sun,
            every: a.every,
            shadows: match (a.no_shadows, a.horizon_shadows) {
                (true, _) => Shadows::Off,
                (false, true) => Shadows::Horizons,
                (false, false) => Shadows::Rays,
            },
            exaggeration: a.exaggerate,
            normals: a.normals,
        };
        let (image, st) = render(&opened, &tracer, &cam, &opts)?;
        write_png(&a.output, &image)?;
        let method = a.method.name();
        if a.json {
            let v = serde_json::json!({ "camera": cam, "method": method, "stats": st });
            println!("{}", serde_json::to_string_pretty(&v)?);
        } else if a.stats {
            println!("{}", render_stats(method, &st));
        }
        s.say(format!("wrote {}", a.output.display()));
        Ok(ExitCode::SUCCESS)
    }
}

/// `render --stats`: rays, speed and the work per primary ray.
pub(crate) fn render_stats(method: &str, st: &RenderStats) -> String {
    format!(
        "{method}: {} primary + {} shadow rays in {:.3} s on {} threads: {:.0} rays/s; per primary ray {:.2} steps, {:.2} cells, {:.2} nodes pushed",
        st.primary_rays,
        st.shadow_rays,
        st.seconds,
        st.threads,
        st.rays_per_second,
        st.mean_steps,
        st.mean_cells,
        st.mean_nodes_pushed
    )
}
