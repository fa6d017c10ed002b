//! Value parsers for command-line flags, shared by the CLI and by the
//! stages' parameter types (which derive clap's `Args`). Each returns the
//! message clap prints after the flag's name.

use terrabake_format::Codec;

use crate::terrain::sun::Sun;

pub(crate) fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or("expected WIDTHxHEIGHT, e.g. 1024x768")?;
    let parse = |v: &str| match v.trim().parse::<u32>() {
        Ok(0) => Err(format!("{v:?}: a size of at least 1")),
        n => n.map_err(|e| format!("{v:?}: {e}")),
    };
    Ok((parse(w)?, parse(h)?))
}

pub(crate) fn parse_cell_size(s: &str) -> Result<(f64, f64), String> {
    let parse = |v: &str| match v.trim().parse::<f64>() {
        Ok(f) if f.is_finite() && f > 0.0 => Ok(f),
        _ => Err(format!("{v:?} is not a positive number of metres")),
    };
    match s.split_once(',') {
        Some((dx, dy)) => Ok((parse(dx)?, parse(dy)?)),
        None => parse(s).map(|d| (d, d)),
    }
}

pub(crate) fn parse_point(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("{p:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err("expected X,Y,Z in metres".into()),
    }
}

/// `X,Y`: two finite numbers (a position in some coordinates).
pub(crate) fn parse_xy(s: &str) -> Result<(f64, f64), String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("{p:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y] if x.is_finite() && y.is_finite() => Ok((x, y)),
        _ => Err(format!("{s:?}: expected X,Y (two numbers)")),
    }
}

pub fn parse_sun(s: &str) -> Result<Sun, String> {
    let (az, el) = s
        .split_once(',')
        .ok_or("expected AZIMUTH,ELEVATION in degrees")?;
    let (azimuth, elevation) = (parse_finite(az)?, parse_finite(el)?);
    if !(-90.0..=90.0).contains(&elevation) {
        return Err(format!(
            "sun elevation {elevation} is not between -90 and 90 degrees"
        ));
    }
    Ok(Sun { azimuth, elevation })
}

/// Refuses a value that is not a positive, finite number, naming its
/// recipe key and its flag: what a recipe can say and the command line's
/// [`parse_positive`] would not let through.
pub(crate) fn check_positive((key, flag): (&str, &str), value: Option<f64>) -> crate::Result<()> {
    match value {
        Some(v) if !(v > 0.0 && v.is_finite()) => {
            crate::error::bail!("{key} = {v} (--{flag} {v}): give a positive number")
        }
        _ => Ok(()),
    }
}

pub fn parse_positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("expected a positive number, not {s:?}")),
    }
}

/// Whether `v` is its type's default: a parameter serde leaves out of a
/// stage's record, so that records from before it was added still match.
pub(crate) fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

/// A finite number, 0 or more.
pub(crate) fn parse_non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("expected a number, 0 or more, not {s:?}")),
    }
}

/// A field of view in degrees, strictly between 0 and 180.
pub(crate) fn parse_fov(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v < 180.0 => Ok(v),
        _ => Err(format!("{s:?} is not between 0 and 180 degrees")),
    }
}

pub(crate) fn parse_on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("{s:?}: expected on or off")),
    }
}

pub(crate) fn parse_aoi(s: &str) -> Result<[u32; 4], String> {
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse::<u32>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("{s:?}: expected X0,Y0,X1,Y1 in posts"))?;
    let [x0, y0, x1, y1]: [u32; 4] = v
        .try_into()
        .map_err(|_| format!("{s:?}: expected four numbers X0,Y0,X1,Y1"))?;
    if x0 >= x1 || y0 >= y1 {
        return Err(format!(
            "{s:?} is empty: columns X0..X1 and rows Y0..Y1 need X0 < X1 and Y0 < Y1"
        ));
    }
    Ok([x0, y0, x1, y1])
}

/// A tile edge: a power of two from 16 to 4096.
pub(crate) fn parse_tile(s: &str) -> Result<u32, String> {
    match s.trim().parse::<u32>() {
        Ok(t) if t.is_power_of_two() && (16..=4096).contains(&t) => Ok(t),
        _ => Err(format!("{s:?} is not a power of two from 16 to 4096")),
    }
}

/// A number of horizon directions: 3 to 4096 (a sector must be narrower
/// than 180 degrees).
pub(crate) fn parse_sectors(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(n) if (3..=4096).contains(&n) => Ok(n),
        _ => Err(format!("{s:?}: give 3 to 4096 directions")),
    }
}

/// Degrees between azimuths for `terrabake profile`: 0.01 to 360.
pub(crate) fn parse_profile_step(s: &str) -> Result<f64, String> {
    parse_within(s, 0.01, 360.0, "degrees (at most 36000 azimuths)")
}

/// Degrees between the directions of `export --for grass`: 0.1 to 360.
pub(crate) fn parse_grass_step(s: &str) -> Result<f64, String> {
    parse_within(s, 0.1, 360.0, "degrees (at most 3600 files)")
}

/// A number from `lo` to `hi` (both included), in `unit`.
fn parse_within(s: &str, lo: f64, hi: f64, unit: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (lo..=hi).contains(&v) => Ok(v),
        _ => Err(format!("{s:?}: give {lo} to {hi} {unit}")),
    }
}

/// The flags (and recipe keys) whose NaN means something: `--nodata nan`
/// says that NaN samples, and no other value, are the source's nodata.
/// Every other number flag and recipe value refuses NaN and infinities
/// (`cli::Cli::parse_checked`, `recipe::Recipe::parse`).
pub const NAN_MEANS_SOMETHING: [&str; 1] = ["nodata"];

/// Any finite number (not NaN, not infinite).
pub(crate) fn parse_finite(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("{s:?} is not a finite number")),
    }
}

/// The codec a stage's tiles are in unless told, for serde.
pub(crate) fn raw() -> Codec {
    Codec::Raw
}

/// Raw tiles are not recorded, so that records from before stages had a
/// codec stay the same.
pub(crate) fn is_raw(codec: &Codec) -> bool {
    *codec == Codec::Raw
}

pub(crate) fn parse_codec(s: &str) -> Result<Codec, String> {
    match s {
        "raw" => Ok(Codec::Raw),
        "zstd" => Ok(Codec::Zstd),
        _ => Err(format!("{s:?}: expected raw or zstd")),
    }
}

/// A flag whose values are the names of `all` (listed in `--help`), for an
/// algorithm enum that knows its names but nothing of clap.
pub fn named<T: Copy + Send + Sync + 'static>(
    all: &'static [T],
    name: fn(T) -> &'static str,
) -> impl clap::builder::TypedValueParser<Value = T> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(all.iter().map(|&v| name(v)))
        .map(move |s| *all.iter().find(|&&v| name(v) == s).expect("a listed name"))
}

/// An area of interest in posts: columns `x0..x1`, rows `y0..y1`.
pub type Aoi = [u32; 4];

/// The area of interest `aoi` as `[x0, y0, x1, y1]` posts, or the whole
/// `w x h` DEM.
pub(crate) fn area_of(aoi: Option<Aoi>, w: usize, h: usize) -> [usize; 4] {
    aoi.unwrap_or([0, 0, w as u32, h as u32])
        .map(|v| v as usize)
}
