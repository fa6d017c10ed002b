//! `terrabake viewshed`: one observer's viewshed from an asset's heights,
//! written as a two-band GeoTIFF with the asset's georeferencing.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use crate::algorithms::viewshed::observer::{observer_viewshed, Observer, OUTSIDE};
use crate::io::cog::{BandMetadata, Cog, Compression, GeoTags, Metadata, Resampling};
use crate::stage::session::{Run, Session};
use crate::stage::sight::SightLines;
use crate::stages::viewshed::{check_height, observer_post, Crs};
use crate::terrain::held::HeldDem;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Band 1 of the GeoTIFF is 1 where the observer sees a target above the \
post and 0 where not; band 2 is the elevation angle of the post from the eye in degrees. Both \
are nodata (NaN) beyond --max-distance and on nodata posts. The surface is the tracers' two \
triangles per cell; docs/VISIBILITY.md compares it with GRASS r.viewshed.\n\n\
Examples:\n  terrabake viewshed out/srtm.tbake --observer -5.5,7.5 --crs lonlat \
--observer-height 10 --max-distance 20000 -o out/viewshed.tif\n  \
terrabake viewshed dem.tbake --observer 600,600 --crs grid -o vs.tif --json"
)]
pub struct ViewshedArgs {
    /// The asset whose heights are seen (its `height` layer).
    pub asset: PathBuf,
    /// Where the observer stands, X,Y in --crs; the nearest post is used.
    #[arg(long, value_parser = crate::stage::args::parse_xy, allow_hyphen_values = true)]
    pub observer: (f64, f64),
    /// The coordinates of --observer: native (the DEM's CRS), lonlat, grid (column,row).
    #[arg(long, value_enum, default_value = "native")]
    pub crs: Crs,
    /// The observer's eye above the ground, metres.
    #[arg(long, default_value_t = crate::stages::viewshed::DEFAULT_EYE_HEIGHT, allow_hyphen_values = true)]
    pub observer_height: f64,
    /// The target above the ground at every post, metres.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub target_height: f64,
    /// How far the observer sees (posts beyond are nodata) and how the Earth bends sight.
    #[command(flatten)]
    pub sight: SightLines,
    /// The GeoTIFF to write (two float32 bands; its directory is created).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// What `terrabake viewshed` reports.
#[derive(Debug, serde::Serialize)]
pub struct ViewshedSummary {
    pub observer_post: (usize, usize),
    pub eye_height_m: f64,
    pub target_height_m: f64,
    pub max_distance_m: Option<f64>,
    pub curvature: f64,
    pub posts_within_reach: u64,
    pub posts_visible: u64,
    pub visible_area_m2: f64,
    pub seconds: f64,
    pub output: PathBuf,
}

impl Run for ViewshedArgs {
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        check_height("--observer-height", self.observer_height)?;
        check_height("--target-height", self.target_height)?;
        self.sight.check()?;
        let asset = crate::stage::asset::open(&self.asset)?;
        let m = asset.manifest();
        let dem = HeldDem::read(&asset)?;
        let (col, row) = observer_post(m, &dem, self.observer, self.crs)?;
        let curvature = self.sight.curvature_coefficient(m);
        let terrain = dem.terrain(curvature);
        let obs = Observer {
            col,
            row,
            height: self.observer_height,
            target_height: self.target_height,
            max_distance: self.sight.max_distance,
        };
        let start = Instant::now();
        let v = observer_viewshed(&terrain, &obs);
        let seconds = start.elapsed().as_secs_f64();
        let w = dem.width;
        let band = |description: &str, unit: &str| BandMetadata {
            description: description.into(),
            unit: unit.into(),
            items: vec![],
        };
        let cog = Cog {
            width: w as u32,
            height: dem.height as u32,
            bands: 2,
            tile: crate::io::cog::DEFAULT_TILE,
            compression: Compression::Deflate,
            resampling: Resampling::Nearest,
            tags: GeoTags::for_level(m.georef.as_ref(), Some("nan".into()), 0),
            metadata: Metadata {
                dataset: vec![("TERRABAKE_VERSION".into(), env!("CARGO_PKG_VERSION").into())],
                bands: vec![
                    band("seen from the observer (1 seen, 0 hidden)", ""),
                    band("elevation angle from the observer", "deg"),
                ],
            },
            overviews: true,
        };
        cog.write(
            &self.output,
            |b, y0, rows| {
                for (i, px) in rows.iter_mut().enumerate() {
                    let at = y0 as usize * w + i;
                    *px = match (b, v.visible[at]) {
                        (0, OUTSIDE) => f32::NAN,
                        (0, seen) => f32::from(seen),
                        _ => v.angle[at],
                    };
                }
                Ok(())
            },
            |_| {},
        )?;
        let reach = v.visible.iter().filter(|&&s| s != OUTSIDE).count() as u64;
        let seen = v.visible.iter().filter(|&&s| s == 1).count() as u64;
        // Area per post at the observer's latitude.
        let post_area = terrain.dx_at(row) * terrain.dy;
        let summary = ViewshedSummary {
            observer_post: (col, row),
            eye_height_m: self.observer_height,
            target_height_m: self.target_height,
            max_distance_m: self.sight.max_distance,
            curvature,
            posts_within_reach: reach,
            posts_visible: seen,
            visible_area_m2: seen as f64 * post_area,
            seconds,
            output: self.output.clone(),
        };
        if self.json {
            println!("{}", serde_json::to_string_pretty(&summary)?);
        }
        s.say(format!(
            "viewshed from post ({col}, {row}), eye {} m, target {} m{}: {seen} of {reach} posts visible ({:.1} %, {:.2} km2) in {seconds:.2} s -> {}",
            self.observer_height,
            self.target_height,
            self.sight.max_distance.map_or(String::new(), |d| format!(", within {d} m")),
            100.0 * seen as f64 / reach.max(1) as f64,
            summary.visible_area_m2 / 1e6,
            self.output.display()
        ));
        Ok(ExitCode::SUCCESS)
    }
}
