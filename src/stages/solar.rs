//! The `solar` stage: clear-sky irradiation and sun hours over days, from
//! the committed `horizon` and `svf_cosine` layers, with r.sun's model
//! (Šúri and Hofierka 2004) shadowed by the horizons as the loader serves
//! them. The model and the shadow kernel are in
//! [`crate::algorithms::solar`]; docs/SOLAR.md has the formulas.
//!
//! Inputs: `height@0` (normals, the air mass), `horizon@0` (every band),
//! `svf_cosine@0`. Outputs: `solar_global`, `solar_beam`,
//! `solar_diffuse`, `solar_reflected` (Wh/m^2 per day, the mean over the
//! days asked) and `sun_hours` (hours per day), f32, one band for the
//! period or, with `monthly`, one per month it touches; NaN on nodata.
//! Reach: one post (the normals), computed tile row by tile row, groups of
//! up to 16 rows of a tile row in parallel, each group sharing one sun
//! path per day (its rows' latitudes rounded to 0.01 degrees).

use std::path::Path;
use std::str::FromStr;

use anyhow::{Context, Result};
use rayon::prelude::*;
use terrabake_format::horizons::{HORIZON, SVF_COSINE};
use terrabake_format::layers as names;
use terrabake_format::{Asset, Codec, ElemType, LayerEntry, LayerWriter, Mmap, HEIGHT_LAYER};

use crate::algorithms::solar::shadow::ShadowRow;
use crate::algorithms::solar::{
    day_steps, levels_spanning, ClearSky, DayStep, Irradiation, RowDay, Surface,
};
use crate::plumbing::progress::Progress;
use crate::stage::post_layer;
use crate::stage::{Share, Stage};
use crate::terrain::tiling::{encode_tile_row, release_tile_row};
use crate::terrain::{RowScale, Terrain};

/// The days a bake covers: `first..=last` of the calendar year.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Days {
    pub first: u32,
    pub last: u32,
}

impl Days {
    pub const YEAR: Days = Days {
        first: 1,
        last: 365,
    };
}

impl FromStr for Days {
    type Err = String;
    /// `172`, `80-100` or `year` (days 1-365).
    fn from_str(s: &str) -> Result<Self, String> {
        let day = |v: &str| -> Result<u32, String> {
            match v.trim().parse::<u32>() {
                Ok(d) if (1..=366).contains(&d) => Ok(d),
                _ => Err(format!(
                    "'{v}' is not a day of the year (1-366); give N, A-B or year"
                )),
            }
        };
        let s = s.trim();
        if s == "year" {
            return Ok(Self::YEAR);
        }
        let (first, last) = match s.split_once('-') {
            Some((a, b)) => (day(a)?, day(b)?),
            None => (day(s)?, day(s)?),
        };
        if first > last {
            return Err(format!("days {first}-{last} run backwards"));
        }
        Ok(Self { first, last })
    }
}

impl std::fmt::Display for Days {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (self.first, self.last) {
            (1, 365) => write!(f, "year"),
            (a, b) if a == b => write!(f, "{a}"),
            (a, b) => write!(f, "{a}-{b}"),
        }
    }
}

impl serde::Serialize for Days {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for Days {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Given {
            Day(u32),
            Text(String),
        }
        match Given::deserialize(d)? {
            Given::Day(n) => n.to_string().parse(),
            Given::Text(s) => s.parse(),
        }
        .map_err(serde::de::Error::custom)
    }
}

/// One of the layers the stage writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolarLayer {
    Global,
    Beam,
    Diffuse,
    Reflected,
    SunHours,
}

impl SolarLayer {
    pub const ALL: [SolarLayer; 5] = [
        SolarLayer::Global,
        SolarLayer::Beam,
        SolarLayer::Diffuse,
        SolarLayer::Reflected,
        SolarLayer::SunHours,
    ];

    pub fn name(self) -> &'static str {
        match self {
            SolarLayer::Global => names::SOLAR_GLOBAL,
            SolarLayer::Beam => names::SOLAR_BEAM,
            SolarLayer::Diffuse => names::SOLAR_DIFFUSE,
            SolarLayer::Reflected => names::SOLAR_REFLECTED,
            SolarLayer::SunHours => names::SUN_HOURS,
        }
    }

    fn what(self) -> &'static str {
        match self {
            SolarLayer::Global => "global irradiation (beam + diffuse + reflected), Wh/m^2 per day",
            SolarLayer::Beam => "beam irradiation, Wh/m^2 per day",
            SolarLayer::Diffuse => "diffuse irradiation, Wh/m^2 per day",
            SolarLayer::Reflected => "ground-reflected irradiation, Wh/m^2 per day",
            SolarLayer::SunHours => {
                "hours per day with the sun's centre above the horizon and in front of the surface"
            }
        }
    }

    /// The layer's value from a post's irradiation over the period, per
    /// step (sun hours count steps; the rest are W/m^2 summed over steps).
    fn value(self, i: &Irradiation) -> f64 {
        match self {
            SolarLayer::Global => i.global(),
            SolarLayer::Beam => i.beam,
            SolarLayer::Diffuse => i.diffuse,
            SolarLayer::Reflected => i.reflected,
            SolarLayer::SunHours => i.sunlit_steps,
        }
    }
}

/// `FROM-TO` hours of the day, `0 <= FROM < TO <= 24`.
fn parse_hours(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s
        .split_once('-')
        .ok_or_else(|| format!("{s:?}: expected FROM-TO hours, e.g. 9-15"))?;
    let hour = |v: &str| match v.trim().parse::<f64>() {
        Ok(h) if (0.0..=24.0).contains(&h) => Ok(h),
        _ => Err(format!("{v:?} is not an hour of the day (0-24)")),
    };
    let (a, b) = (hour(a)?, hour(b)?);
    if a >= b {
        return Err(format!("{s:?}: the hours run backwards or are empty"));
    }
    Ok((a, b))
}

/// The month (1-12) of day `day` of `year`.
fn month_of(year: i32, day: u32) -> u32 {
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    let lengths = [
        31,
        if leap { 29 } else { 28 },
        31,
        30,
        31,
        30,
        31,
        31,
        30,
        31,
        30,
        31,
    ];
    let mut left = day;
    for (m, len) in lengths.into_iter().enumerate() {
        if left <= len {
            return m as u32 + 1;
        }
        left -= len;
    }
    12
}

const MONTHS: [&str; 12] = [
    "January",
    "February",
    "March",
    "April",
    "May",
    "June",
    "July",
    "August",
    "September",
    "October",
    "November",
    "December",
];

/// The days one band of the outputs is the mean over.
#[derive(Debug, Clone, PartialEq)]
pub struct Period {
    /// "day 172 of 2026", "mean day of days 1-365 of 2026", "mean day of
    /// June 2026".
    pub label: String,
    pub days: Vec<u32>,
}

/// The `solar` stage and its parameters (`terrabake solar`, recipe step `solar`).
#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolarStage {
    /// The days: one day of the year (`--day 172`), a range (`--days 80-100`) or `year`
    /// (days 1-365; also `--year`). The outputs are the mean day over them.
    #[arg(long, visible_alias = "day", default_value = "year", value_parser = Days::from_str)]
    pub days: Days,
    /// One band per month the days touch, each the mean day of that month, instead of one
    /// band for the whole period.
    #[arg(long)]
    pub monthly: bool,
    /// Minutes between sun positions (each taken at the middle of its step of local apparent
    /// solar time).
    #[arg(long = "step", value_name = "MINUTES", default_value_t = SolarStage::DEFAULT_STEP)]
    pub step_minutes: f64,
    /// Linke turbidity factor of the clear sky (at air mass 2): 2 very clear, 3 rural
    /// Europe (r.sun's default), 4-6 hazy or urban.
    #[arg(long, default_value_t = SolarStage::DEFAULT_LINKE)]
    pub linke: f64,
    /// Twelve Linke factors, January to December, instead of --linke (the monthly values
    /// PVGIS and SoDa publish).
    #[arg(
        long = "linke-monthly",
        value_delimiter = ',',
        num_args = 1,
        value_name = "T1,...,T12"
    )]
    pub linke_monthly: Option<Vec<f64>>,
    /// Ground albedo, 0-1, for the reflected part.
    #[arg(long, default_value_t = SolarStage::DEFAULT_ALBEDO)]
    pub albedo: f64,
    /// Latitude in degrees, north positive: needed where the DEM is neither geographic nor
    /// WGS 84 UTM; otherwise each row's own latitude is taken from the georeferencing.
    #[arg(long = "lat", value_name = "DEG", allow_negative_numbers = true)]
    pub latitude: Option<f64>,
    /// Longitude in degrees, east positive (the instant of each step, for the declination):
    /// from the georeferencing where it has one, else 0.
    #[arg(long = "lon", value_name = "DEG", allow_negative_numbers = true)]
    pub longitude: Option<f64>,
    /// Only the steps between two hours of local apparent solar time, `FROM-TO` (`9-15`):
    /// irradiation and sun hours within them (the sun hours over `TO - FROM` are the share
    /// of that time in daylight, WhiteboxTools' time_in_daylight).
    #[arg(long, value_name = "FROM-TO", value_parser = parse_hours)]
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub between: Option<(f64, f64)>,
    /// The calendar year the days are of (the sun's declination on a day moves by up to
    /// 0.2 degrees over a leap cycle).
    #[arg(long = "calendar-year", value_name = "YEAR", default_value_t = crate::terrain::sun::PATH_YEAR)]
    pub calendar_year: i32,
    /// Tiles of the layers written: raw (read in place from the mapping, what a renderer
    /// wants) or zstd (smaller: horizon angles about 3x, sky and solar layers 1.5-2x;
    /// decoded into a cache on read).
    #[arg(long, value_parser = crate::stage::args::parse_codec, default_value = "raw")]
    #[serde(
        default = "crate::stage::args::raw",
        skip_serializing_if = "crate::stage::args::is_raw"
    )]
    pub codec: Codec,
}

impl SolarStage {
    pub const DEFAULT_STEP: f64 = 15.0;
    pub const DEFAULT_LINKE: f64 = 3.0;
    pub const DEFAULT_ALBEDO: f64 = 0.2;

    /// The bands of the outputs, in order.
    pub fn periods(&self) -> Vec<Period> {
        let Days { first, last } = self.days;
        let year = self.calendar_year;
        if !self.monthly {
            let label = if first == last {
                format!("day {first} of {year}")
            } else {
                format!("mean day of days {first}-{last} of {year}")
            };
            return vec![Period {
                label,
                days: (first..=last).collect(),
            }];
        }
        let mut out: Vec<Period> = Vec::new();
        for day in first..=last {
            let month = month_of(year, day);
            let label = format!("mean day of {} {year}", MONTHS[month as usize - 1]);
            match out.last_mut() {
                Some(p) if p.label == label => p.days.push(day),
                _ => out.push(Period {
                    label,
                    days: vec![day],
                }),
            }
        }
        out
    }

    /// The Linke turbidity on day `day`.
    fn linke_on(&self, day: u32) -> f64 {
        match &self.linke_monthly {
            Some(t) => t[month_of(self.calendar_year, day) as usize - 1],
            None => self.linke,
        }
    }

    fn description(&self, layer: SolarLayer) -> String {
        let linke = match &self.linke_monthly {
            Some(t) => format!(
                "Linke {} by month",
                t.iter()
                    .map(|v| v.to_string())
                    .collect::<Vec<_>>()
                    .join(",")
            ),
            None => format!("Linke {}", self.linke),
        };
        format!(
            "{}{}, {}: r.sun's clear-sky model (Suri and Hofierka 2004), {linke}, albedo {}, {}-minute steps, shadowed by the stored horizons",
            layer.what(),
            self.between.map_or(String::new(), |(a, b)| {
                format!(" between {a} and {b} h local solar time")
            }),
            self.periods()
                .iter()
                .map(|p| p.label.as_str())
                .collect::<Vec<_>>()
                .join("; "),
            self.albedo,
            self.step_minutes
        )
    }
}

impl Default for SolarStage {
    fn default() -> Self {
        Self {
            days: Days::YEAR,
            monthly: false,
            step_minutes: Self::DEFAULT_STEP,
            linke: Self::DEFAULT_LINKE,
            linke_monthly: None,
            albedo: Self::DEFAULT_ALBEDO,
            latitude: None,
            longitude: None,
            between: None,
            calendar_year: crate::terrain::sun::PATH_YEAR,
            codec: Codec::Raw,
        }
    }
}

impl Stage for SolarStage {
    fn name(&self) -> &'static str {
        "solar"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("parameters serialise")
    }

    fn inputs(&self) -> Vec<String> {
        vec![
            format!("{HEIGHT_LAYER}@0"),
            format!("{HORIZON}@0"),
            format!("{SVF_COSINE}@0"),
        ]
    }

    fn check(&self) -> crate::Result<()> {
        use crate::error::ensure;
        let s = self.step_minutes;
        ensure!(
            s.is_finite() && (0.5..=60.0).contains(&s) && (1440.0 / s).fract() == 0.0,
            "step = {s} (--step) must divide a day into whole steps of 0.5 to 60 minutes (15, 10, 5, ...)"
        );
        let linkes = self
            .linke_monthly
            .clone()
            .unwrap_or_else(|| vec![self.linke]);
        if let Some(t) = &self.linke_monthly {
            ensure!(
                t.len() == 12,
                "linke_monthly (--linke-monthly) has {} values; give twelve, January to December",
                t.len()
            );
        }
        for t in linkes {
            ensure!(
                t.is_finite() && (1.0..=10.0).contains(&t),
                "Linke turbidity {t} (--linke) is outside 1-10 (2 very clear, 3 rural, 6 urban haze)"
            );
        }
        ensure!(
            (0.0..=1.0).contains(&self.albedo),
            "albedo = {} (--albedo) must lie in 0-1",
            self.albedo
        );
        if let Some(lat) = self.latitude {
            ensure!(
                (-90.0..=90.0).contains(&lat),
                "latitude {lat} (--lat) must lie in -90 to 90"
            );
        }
        if let Some(lon) = self.longitude {
            ensure!(
                (-180.0..=360.0).contains(&lon),
                "longitude {lon} (--lon) must lie in -180 to 360"
            );
        }
        if let Some((from, to)) = self.between {
            ensure!(
                (0.0..=24.0).contains(&from) && (0.0..=24.0).contains(&to) && from < to,
                "between = [{from}, {to}] (--between) must be two hours of the day, 0-24, the first earlier"
            );
        }
        ensure!(
            (1900..=2100).contains(&self.calendar_year),
            "calendar_year {} (--calendar-year) is outside 1900-2100, where the ephemeris holds",
            self.calendar_year
        );
        Ok(())
    }

    fn outputs(&self, _: &terrabake_format::Manifest) -> Vec<String> {
        SolarLayer::ALL
            .iter()
            .map(|l| format!("{}@0", l.name()))
            .collect()
    }

    /// The normals need the posts around each post.
    fn reach(&self, _: &terrabake_format::Manifest) -> crate::stage::Reach {
        crate::stage::Reach::Posts(1)
    }

    /// A tile row of heights and of every output band, and per thread a
    /// group of rows' horizon bands and kernel sums.
    fn memory(&self, m: &terrabake_format::Manifest) -> Option<u64> {
        let (w, ts) = (u64::from(m.width), u64::from(m.tile_size));
        let bands = m.layer(HORIZON, 0).map_or(64, |l| u64::from(l.bands));
        let periods = self.periods().len() as u64;
        let threads = rayon::current_num_threads() as u64;
        let tile_row = (ts + 2) * w * 4 + 2 * SolarLayer::ALL.len() as u64 * periods * ts * w * 4;
        // A row of every band, the kernel's sums at three levels, the
        // normals (f64 and f32), the levels' weights and the row's values.
        let kept = (crate::algorithms::solar::LEVELS * crate::algorithms::solar::COMPONENTS) as u64;
        let per_row = w * (bands * 4 + kept * 8 + 7 * 8 + 8);
        Some(tile_row + threads * GROUP_ROWS as u64 * per_row)
    }

    /// Tile rows outside the share's rows are left at the fill value.
    fn run(
        &self,
        asset: &Asset<Mmap>,
        dir: &Path,
        share: &Share,
        progress: Progress,
    ) -> crate::Result<Vec<LayerEntry>> {
        let m = asset.manifest();
        let height = asset.height()?;
        let horizon = asset
            .layer(HORIZON, 0)
            .context("the asset has no horizon layer; run `terrabake horizons` first")?;
        let svf_cosine = asset.layer(SVF_COSINE, 0).context(
            "the asset has no svf_cosine layer; run `terrabake sky --layers svf_cosine` first",
        )?;
        let (w, h, ts) = (
            height.width() as usize,
            height.height() as usize,
            height.tile_size() as usize,
        );
        let azimuths = horizon.entry().band_azimuths.clone();
        let bands = azimuths.len();
        let georef = m.georef.as_ref();
        let latitudes: Vec<f64> = match (self.latitude, georef) {
            (Some(lat), _) => vec![lat; h],
            (None, Some(g)) => crate::terrain::geo::row_latitudes(g, w as u32, h as u32)
                .with_context(|| {
                    format!(
                        "{}: the DEM's CRS is neither geographic nor WGS 84 UTM, so its latitude is unknown; give --lat",
                        asset.dir().display()
                    )
                })
                .map_err(|e| crate::error::mark(crate::ErrorKind::Parameters, e))?,
            (None, None) => crate::error::bail!(
                "{}: the DEM is not georeferenced, so its latitude is unknown; give --lat (and --lon)",
                asset.dir().display()
            ),
        };
        let longitude = self
            .longitude
            .or_else(|| {
                georef.and_then(|g| crate::terrain::geo::central_longitude(g, w as u32, h as u32))
            })
            .unwrap_or(0.0);
        let convergence = georef.map_or(0.0, |g| {
            crate::terrain::geo::grid_convergence(g, w as u32, h as u32)
        });
        let periods = self.periods();
        let steps: Vec<Vec<DayStep>> = (self.days.first..=self.days.last)
            .map(|day| {
                let mut steps = day_steps(self.calendar_year, day, self.step_minutes, longitude);
                if let Some((from, to)) = self.between {
                    steps.retain(|s| (from..to).contains(&s.solar_hours()));
                }
                steps
            })
            .collect();
        let step_hours = self.step_minutes / 60.0;
        let row_scale = crate::terrain::geo::row_scale(georef, h as u32);
        let row_scale = RowScale::new(&row_scale);
        let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
        let mut writers = SolarLayer::ALL
            .iter()
            .map(|&l| {
                let spec = post_layer(
                    (l.name(), "solar"),
                    ElemType::F32,
                    periods.len() as u32,
                    (w, h, ts),
                    self.description(l),
                    self.codec,
                );
                Ok((l, LayerWriter::create(dir, spec)?))
            })
            .collect::<Result<Vec<_>>>()?;
        let tiles_y = h.div_ceil(ts);
        let tiles_x = w.div_ceil(ts);
        let bar = progress.bar(h as u64, "solar", "rows");
        let wanted = share.rows(h);
        let mut z = Vec::new();
        let mut svf = vec![0f32; 0];
        // values[layer][period][row * w + x]
        let mut values: Vec<Vec<Vec<f32>>> =
            vec![vec![Vec::new(); periods.len()]; SolarLayer::ALL.len()];
        for (ty, y0) in (0..h).step_by(ts).enumerate() {
            let rows = ts.min(h - y0);
            if y0 >= wanted.end || y0 + rows <= wanted.start {
                for (_, writer) in &mut writers {
                    for p in 0..periods.len() {
                        for tx in 0..tiles_x {
                            writer.push_fill_at(((p * tiles_y + ty) * tiles_x + tx) as u64)?;
                        }
                    }
                }
                bar.inc(rows as u64);
                continue;
            }
            let (r0, r1) = (y0.saturating_sub(1), (y0 + rows + 1).min(h));
            z.resize((r1 - r0) * w, 0.0);
            height.read_window(0, 0, r0 as u32, w as u32, (r1 - r0) as u32, &mut z)?;
            svf.resize(rows * w, 0.0);
            svf_cosine.read_rows_f32(0, y0 as u32, &mut svf)?;
            let terrain = Terrain::window(&z, (w, h), r0, (dx, dy)).with_row_scale(row_scale);
            // Each row's values, [layer][period][x], by groups of rows that
            // share their sun paths, the groups in parallel.
            let key = |row: usize| self.path_latitude(latitudes[row]);
            let mut groups: Vec<std::ops::Range<usize>> = Vec::new();
            for r in 0..rows {
                match groups.last_mut() {
                    Some(g) if g.len() < GROUP_ROWS && key(y0 + g.start) == key(y0 + r) => {
                        g.end = r + 1
                    }
                    _ => groups.push(r..r + 1),
                }
            }
            let row_values: Vec<Vec<Vec<Vec<f32>>>> = groups
                .into_par_iter()
                .map(|g| -> terrabake_format::Result<Vec<Vec<Vec<Vec<f32>>>>> {
                    let mut angles = vec![0f32; g.len() * bands * w];
                    for (i, rows_angles) in angles.chunks_mut(bands * w).enumerate() {
                        for b in 0..bands {
                            horizon.read_rows_f32(
                                b as u32,
                                (y0 + g.start + i) as u32,
                                &mut rows_angles[b * w..][..w],
                            )?;
                        }
                    }
                    let out = self.rows(
                        RowsInputs {
                            terrain: &terrain,
                            rows: y0 + g.start..y0 + g.end,
                            angles: &angles,
                            svf_cosine: &svf[g.start * w..g.end * w],
                            latitude: (key(y0 + g.start), convergence),
                            azimuths: &azimuths,
                        },
                        &steps,
                        &periods,
                        step_hours,
                    );
                    bar.inc(g.len() as u64);
                    Ok(out)
                })
                .collect::<terrabake_format::Result<Vec<_>>>()?
                .into_iter()
                .flatten()
                .collect();
            release_tile_row(horizon, ty as u32)?;
            release_tile_row(svf_cosine, ty as u32)?;
            for (li, (_, writer)) in writers.iter_mut().enumerate() {
                for (p, values) in values[li].iter_mut().enumerate() {
                    values.clear();
                    for rv in &row_values {
                        values.extend_from_slice(&rv[li][p]);
                    }
                    for (tx, tile) in encode_tile_row(values, w, ts, f32::NAN, self.codec)
                        .into_iter()
                        .enumerate()
                    {
                        writer.push_at(((p * tiles_y + ty) * tiles_x + tx) as u64, tile)?;
                    }
                }
            }
        }
        bar.finish_and_clear();
        writers.into_iter().map(|(_, w)| Ok(w.finish()?)).collect()
    }
}

/// At most this many rows share one computation of each day's sun path
/// ([`RowDay`]): enough to make it a small part of the stage's time, few
/// enough that their horizon rows and kernels stay small.
const GROUP_ROWS: usize = 16;

/// Rows whose latitudes round to the same multiple of this many degrees
/// take their sun paths at that multiple (0.01 degrees, 1.1 km): the sun's
/// elevation there differs from the row's own by at most 0.005 degrees,
/// under a second of its daily path, where a 15-minute step spans 3.75
/// degrees. The multiple depends on nothing but the row's latitude, so a
/// crop gives the same bits.
const LATITUDE_QUANTUM: f64 = 0.01;

/// What one group of rows' computation reads.
struct RowsInputs<'a> {
    terrain: &'a Terrain<'a>,
    rows: std::ops::Range<usize>,
    /// Every horizon band's angles on each row: row after row, band after
    /// band.
    angles: &'a [f32],
    svf_cosine: &'a [f32],
    /// The rows' shared latitude and the grid's convergence, degrees.
    latitude: (f64, f64),
    azimuths: &'a [f64],
}

impl SolarStage {
    /// The latitude a row's sun paths are taken at: `--lat` as given, else
    /// the row's own rounded to [`LATITUDE_QUANTUM`].
    fn path_latitude(&self, row_latitude: f64) -> f64 {
        match self.latitude {
            Some(given) => given,
            None => (row_latitude / LATITUDE_QUANTUM).round() * LATITUDE_QUANTUM,
        }
    }

    /// Each row's values, `[row][layer][period][x]`: every day of each
    /// period through each row's shadow kernel, one sun path a day for the
    /// whole group (at levels spanning all its heights, which give every
    /// post the same sums as its own row's levels would: they are fixed
    /// heights), then each post's sums on its surface.
    fn rows(
        &self,
        input: RowsInputs,
        steps: &[Vec<DayStep>],
        periods: &[Period],
        step_hours: f64,
    ) -> Vec<Vec<Vec<Vec<f32>>>> {
        let RowsInputs {
            terrain,
            rows,
            angles,
            svf_cosine,
            latitude,
            azimuths,
        } = input;
        let w = terrain.width;
        let bands = azimuths.len();
        struct Row<'a> {
            normals: Vec<[f64; 3]>,
            z: Vec<f32>,
            valid: Vec<bool>,
            angles: &'a [f32],
            svf_cosine: &'a [f32],
        }
        let rows: Vec<Row> = rows
            .enumerate()
            .map(|(i, row)| {
                let normals: Vec<[f64; 3]> = (0..w)
                    .map(|x| terrain.normal(x, row).unwrap_or([f64::NAN; 3]))
                    .collect();
                let z: Vec<f32> = (0..w).map(|x| terrain.at(x, row)).collect();
                let angles = &angles[i * bands * w..][..bands * w];
                let svf_cosine = &svf_cosine[i * w..][..w];
                // A post is computed where it has a height, a normal, a
                // sky-view factor and every horizon band.
                let valid = (0..w)
                    .map(|x| {
                        !z[x].is_nan()
                            && !normals[x][2].is_nan()
                            && !svf_cosine[x].is_nan()
                            && (0..bands).all(|b| !angles[b * w + x].is_nan())
                    })
                    .collect();
                Row {
                    normals,
                    z,
                    valid,
                    angles,
                    svf_cosine,
                }
            })
            .collect();
        let mut out =
            vec![vec![vec![vec![f32::NAN; w]; periods.len()]; SolarLayer::ALL.len()]; rows.len()];
        let (lo, hi) = rows
            .iter()
            .flat_map(|r| r.z.iter().zip(&r.valid))
            .filter(|(_, &v)| v)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), (&z, _)| {
                (a.min(f64::from(z)), b.max(f64::from(z)))
            });
        if lo > hi {
            return out;
        }
        let levels = levels_spanning(lo, hi);
        let mut kernels: Vec<ShadowRow> = rows
            .iter()
            .map(|r| ShadowRow::new(&r.normals, &r.z, r.angles, levels))
            .collect();
        for (p, period) in periods.iter().enumerate() {
            kernels.iter_mut().for_each(ShadowRow::clear);
            for &day in &period.days {
                let sky = ClearSky {
                    linke: self.linke_on(day),
                };
                let day_steps = &steps[(day - self.days.first) as usize];
                let path = RowDay::new(day_steps, latitude, azimuths, sky, levels);
                kernels.iter_mut().for_each(|k| k.add_day(&path));
            }
            let scale = step_hours / period.days.len() as f64;
            for ((row, kernel), out) in rows.iter().zip(&kernels).zip(&mut out) {
                for x in (0..w).filter(|&x| row.valid[x]) {
                    let surface = Surface {
                        normal: row.normals[x],
                        svf_cosine: f64::from(row.svf_cosine[x]),
                        albedo: self.albedo,
                    };
                    let irradiation = kernel.sums(x).irradiation(&surface);
                    for (l, layer) in SolarLayer::ALL.iter().enumerate() {
                        out[l][p][x] = (layer.value(&irradiation) * scale) as f32;
                    }
                }
            }
        }
        out
    }
}
