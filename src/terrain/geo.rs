//! Georeferencing: the GeoTIFF GeoKey directory (OGC GeoTIFF 1.1, sec. 7)
//! read for what terrabake needs, and the metric post spacing of a grid.

use terrabake_format::manifest::{CellSize, CrsKind, Georef, RasterType};

pub const GT_MODEL_TYPE: u16 = 1024;
pub const GT_RASTER_TYPE: u16 = 1025;
pub const GEOGRAPHIC_TYPE: u16 = 2048;
pub const PROJECTED_CS_TYPE: u16 = 3072;
pub const PROJ_LINEAR_UNITS: u16 = 3076;

/// WGS84 semi-major axis and first eccentricity squared.
const WGS84_A: f64 = 6_378_137.0;
const WGS84_E2: f64 = 6.694_379_990_14e-3;

/// One key's SHORT value from a GeoKeyDirectory (values stored in other tags
/// are not SHORT and are ignored here).
pub(crate) fn geo_key(dir: &[u16], key: u16) -> Option<u16> {
    let count = usize::from(*dir.get(3)?);
    dir.get(4..4 + 4 * count)?
        .chunks_exact(4)
        .find(|k| k[0] == key && k[1] == 0 && k[2] == 1)
        .map(|k| k[3])
}

/// Builds a `Georef` from a GeoKey directory and a raster-to-model transform.
pub fn georef_from_keys(
    dir: Vec<u16>,
    doubles: Vec<f64>,
    ascii: String,
    geotransform: [f64; 6],
) -> Georef {
    let crs_kind = match geo_key(&dir, GT_MODEL_TYPE) {
        Some(1) => CrsKind::Projected,
        Some(2) => CrsKind::Geographic,
        _ => CrsKind::Unknown,
    };
    let raster_type = match geo_key(&dir, GT_RASTER_TYPE) {
        Some(2) => RasterType::Point,
        _ => RasterType::Area,
    };
    let code = match crs_kind {
        CrsKind::Projected => geo_key(&dir, PROJECTED_CS_TYPE),
        CrsKind::Geographic => geo_key(&dir, GEOGRAPHIC_TYPE),
        _ => None,
    };
    // 32767 is "user-defined" and 0 "undefined": no EPSG code.
    let epsg = code.filter(|&c| c != 0 && c != 32767).map(u32::from);
    Georef {
        crs_kind,
        epsg,
        geotransform,
        raster_type,
        geo_key_directory: dir,
        geo_double_params: doubles,
        geo_ascii_params: ascii,
    }
}

/// Metres per unit of a projected CRS's ProjLinearUnitsGeoKey (EPSG codes).
pub(crate) fn linear_unit_metres(dir: &[u16]) -> f64 {
    match geo_key(dir, PROJ_LINEAR_UNITS) {
        Some(9002) => 0.3048,
        Some(9003) => 1200.0 / 3937.0,
        _ => 1.0,
    }
}

/// Metres per radian of longitude and of latitude at latitude `phi`
/// (radians) on the WGS84 ellipsoid: the parallel's radius and the
/// meridian's radius of curvature.
fn metres_per_radian(phi: f64) -> (f64, f64) {
    let w = (1.0 - WGS84_E2 * phi.sin().powi(2)).sqrt();
    let prime_vertical = WGS84_A / w;
    let meridional = WGS84_A * (1.0 - WGS84_E2) / (w * w * w);
    (prime_vertical * phi.cos(), meridional)
}

/// Latitude (radians) of row `row` of a geographic grid.
fn row_latitude(georef: &Georef, row: f64) -> f64 {
    georef.post_to_world(0.0, row).1.to_radians()
}

/// Metric post spacing (dx, dy) of a georeferenced grid of `height` rows.
/// Geographic grids are measured at the centre row on the WGS84 ellipsoid:
/// the east-west spacing varies with latitude, and the horizon stage takes
/// it per row ([`row_scale`]).
pub fn cell_size(georef: &Georef, height: u32, linear_unit_m: f64) -> CellSize {
    let t = &georef.geotransform;
    let (sx, sy) = (t[1].hypot(t[4]), t[2].hypot(t[5]));
    match georef.crs_kind {
        CrsKind::Geographic => {
            let (east, north) = metres_per_radian(row_latitude(georef, f64::from(height) / 2.0));
            CellSize {
                dx: sx.to_radians() * east,
                dy: sy.to_radians() * north,
                source: "geographic-centre".into(),
            }
        }
        _ => CellSize {
            dx: sx * linear_unit_m,
            dy: sy * linear_unit_m,
            source: "projected".into(),
        },
    }
}

/// The east-west post spacing of every half row relative to the centre
/// row's (`cell_size`'s `dx`), for `horizon::terrain::RowScale`: entry `2 r`
/// at row `r`, `2 r + 1` midway to row `r + 1`. Empty (uniform) unless the
/// grid is geographic.
pub fn row_scale(georef: Option<&Georef>, height: u32) -> Vec<f64> {
    let Some(georef) = georef.filter(|g| g.crs_kind == CrsKind::Geographic) else {
        return Vec::new();
    };
    let centre = metres_per_radian(row_latitude(georef, f64::from(height) / 2.0)).0;
    (0..(2 * height).saturating_sub(1))
        .map(|half| metres_per_radian(row_latitude(georef, f64::from(half) / 2.0)).0 / centre)
        .collect()
}

/// The latitude (degrees) at the centre of a `w x h` grid: exact on
/// geographic grids; on WGS 84 UTM grids the footpoint latitude of the
/// centre's northing on a sphere of the rectifying radius (within 0.2
/// degrees: enough for a sun path); `None` otherwise.
pub(crate) fn central_latitude(georef: &Georef, w: u32, h: u32) -> Option<f64> {
    latitude_at(georef, f64::from(w) / 2.0, f64::from(h) / 2.0)
}

/// The latitude (degrees) of post `(col, row)`, as [`central_latitude`].
fn latitude_at(georef: &Georef, col: f64, row: f64) -> Option<f64> {
    let (_, y) = georef.post_to_world(col, row);
    match georef.crs_kind {
        CrsKind::Geographic => Some(y),
        _ => {
            let (_, south) = utm_zone(georef.epsg?)?;
            let northing = if south { y - 10_000_000.0 } else { y };
            Some((northing / K0_RECTIFYING_RADIUS).to_degrees())
        }
    }
}

/// UTM's scale on the central meridian times the WGS 84 rectifying radius.
const K0_RECTIFYING_RADIUS: f64 = 0.9996 * 6_367_449.146;

/// The latitude (degrees) of every row of a `w x h` grid at its centre
/// column, as [`central_latitude`] takes it.
pub(crate) fn row_latitudes(georef: &Georef, w: u32, h: u32) -> Option<Vec<f64>> {
    (0..h)
        .map(|row| latitude_at(georef, f64::from(w) / 2.0, f64::from(row)))
        .collect()
}

/// The longitude (degrees east) at the centre of a `w x h` grid: exact on
/// geographic grids; on UTM grids the zone's meridian plus the centre's
/// easting over the parallel's radius (within a few hundredths of a
/// degree inside a zone); `None` otherwise.
pub(crate) fn central_longitude(georef: &Georef, w: u32, h: u32) -> Option<f64> {
    let (x, _) = georef.post_to_world(f64::from(w) / 2.0, f64::from(h) / 2.0);
    match georef.crs_kind {
        CrsKind::Geographic => Some(x),
        _ => {
            let (zone, _) = utm_zone(georef.epsg?)?;
            let phi = central_latitude(georef, w, h)?.to_radians();
            let meridian = f64::from(zone) * 6.0 - 183.0;
            Some(meridian + ((x - 500_000.0) / (K0_RECTIFYING_RADIUS * phi.cos())).to_degrees())
        }
    }
}

/// The grid convergence (degrees) at the centre of a `w x h` grid: the
/// angle from true north to grid north, clockwise, so that a true
/// azimuth `A` is the grid azimuth `A - convergence`. 0 on geographic grids;
/// on UTM grids `atan(tan(lon - lon0) sin lat)` (Snyder 1987, eq. 8-15
/// to first order), within 0.01 degrees inside a zone.
pub(crate) fn grid_convergence(georef: &Georef, w: u32, h: u32) -> f64 {
    if georef.crs_kind == CrsKind::Geographic {
        return 0.0;
    }
    let (Some((zone, _)), Some(lon), Some(lat)) = (
        georef.epsg.and_then(utm_zone),
        central_longitude(georef, w, h),
        central_latitude(georef, w, h),
    ) else {
        return 0.0;
    };
    let dlon = (lon - (f64::from(zone) * 6.0 - 183.0)).to_radians();
    (dlon.tan() * lat.to_radians().sin()).atan().to_degrees()
}

/// The UTM zone of an EPSG code on WGS 84 (326zz north, 327zz south):
/// `(zone, south)`.
pub(crate) fn utm_zone(epsg: u32) -> Option<(u32, bool)> {
    match epsg {
        32601..=32660 => Some((epsg - 32600, false)),
        32701..=32760 => Some((epsg - 32700, true)),
        _ => None,
    }
}

/// The WKT (OGC WKT 1) of EPSG code `epsg`, from the EPSG database that
/// `crs-definitions` carries as data; `None` for a code it does not know.
pub fn wkt(epsg: u32) -> Option<String> {
    let def = crs_definitions::from_code(u16::try_from(epsg).ok()?)?;
    Some(def.wkt.to_string())
}

/// CF's grid mapping attributes (CF-1.8, Appendix F) of EPSG code `epsg`:
/// `grid_mapping_name`, the projection's parameters and the ellipsoid's,
/// read from the code's PROJ definition in the EPSG database
/// `crs-definitions` carries. Covers latitude-longitude, transverse
/// Mercator (UTM among them), polar and oblique stereographic, Lambert
/// conformal conic, Albers, Lambert azimuthal equal-area and Mercator;
/// `None` for other projections, which keep `crs_wkt` alone (what GDAL and
/// rioxarray read first anyway).
pub fn cf_grid_mapping(epsg: u32) -> Option<Vec<(&'static str, CfValue)>> {
    let def = crs_definitions::from_code(u16::try_from(epsg).ok()?)?;
    cf_grid_mapping_of_proj4(def.proj4)
}

/// A CF attribute's value: a number or a pair of standard parallels.
#[derive(Debug, Clone, PartialEq)]
pub enum CfValue {
    Number(f64),
    Numbers(Vec<f64>),
    Text(&'static str),
}

fn cf_grid_mapping_of_proj4(proj4: &str) -> Option<Vec<(&'static str, CfValue)>> {
    use CfValue::{Number, Numbers, Text};
    let params: Vec<(&str, &str)> = proj4
        .split_whitespace()
        .filter_map(|p| p.strip_prefix('+'))
        .map(|p| p.split_once('=').unwrap_or((p, "")))
        .collect();
    let text = |key: &str| params.iter().find(|(k, _)| *k == key).map(|(_, v)| *v);
    let num = |key: &str| text(key).and_then(|v| v.parse::<f64>().ok());
    let or0 = |key: &str| num(key).unwrap_or(0.0);
    let scale = || num("k").or(num("k_0")).unwrap_or(1.0);
    let mut out: Vec<(&'static str, CfValue)> = Vec::new();
    // A standard parallel off the pole (NSIDC's 70 N, with a nominal k=1
    // beside it), else the scale at the origin (UPS: lat_ts=90 with
    // k=0.994).
    let parallel_or_scale = |out: &mut Vec<(&'static str, CfValue)>| match num("lat_ts")
        .filter(|ts| ts.abs() != 90.0)
    {
        Some(ts) => out.push(("standard_parallel", Number(ts))),
        None => out.push(("scale_factor_at_projection_origin", Number(scale()))),
    };
    let false_origin = |out: &mut Vec<(&'static str, CfValue)>| {
        out.push(("false_easting", Number(or0("x_0"))));
        out.push(("false_northing", Number(or0("y_0"))));
    };
    match text("proj")? {
        "longlat" => out.push(("grid_mapping_name", Text("latitude_longitude"))),
        "utm" => {
            let zone: f64 = num("zone")?;
            out.push(("grid_mapping_name", Text("transverse_mercator")));
            out.push(("scale_factor_at_central_meridian", Number(0.9996)));
            out.push(("longitude_of_central_meridian", Number(6.0 * zone - 183.0)));
            out.push(("latitude_of_projection_origin", Number(0.0)));
            out.push(("false_easting", Number(500_000.0)));
            let south = text("south").is_some();
            out.push(("false_northing", Number(if south { 1e7 } else { 0.0 })));
        }
        "tmerc" => {
            out.push(("grid_mapping_name", Text("transverse_mercator")));
            out.push(("scale_factor_at_central_meridian", Number(scale())));
            out.push(("longitude_of_central_meridian", Number(or0("lon_0"))));
            out.push(("latitude_of_projection_origin", Number(or0("lat_0"))));
            false_origin(&mut out);
        }
        "stere" if or0("lat_0").abs() == 90.0 => {
            out.push(("grid_mapping_name", Text("polar_stereographic")));
            out.push((
                "straight_vertical_longitude_from_pole",
                Number(or0("lon_0")),
            ));
            out.push(("latitude_of_projection_origin", Number(or0("lat_0"))));
            parallel_or_scale(&mut out);
            false_origin(&mut out);
        }
        "stere" | "sterea" => {
            out.push(("grid_mapping_name", Text("stereographic")));
            out.push(("longitude_of_projection_origin", Number(or0("lon_0"))));
            out.push(("latitude_of_projection_origin", Number(or0("lat_0"))));
            out.push(("scale_factor_at_projection_origin", Number(scale())));
            false_origin(&mut out);
        }
        proj @ ("lcc" | "aea") => {
            let name = if proj == "lcc" {
                "lambert_conformal_conic"
            } else {
                "albers_conical_equal_area"
            };
            out.push(("grid_mapping_name", Text(name)));
            let parallels: Vec<f64> = [num("lat_1"), num("lat_2")].into_iter().flatten().collect();
            out.push(("standard_parallel", Numbers(parallels)));
            out.push(("longitude_of_central_meridian", Number(or0("lon_0"))));
            out.push(("latitude_of_projection_origin", Number(or0("lat_0"))));
            false_origin(&mut out);
        }
        "laea" => {
            out.push(("grid_mapping_name", Text("lambert_azimuthal_equal_area")));
            out.push(("longitude_of_projection_origin", Number(or0("lon_0"))));
            out.push(("latitude_of_projection_origin", Number(or0("lat_0"))));
            false_origin(&mut out);
        }
        "merc" => {
            out.push(("grid_mapping_name", Text("mercator")));
            out.push(("longitude_of_projection_origin", Number(or0("lon_0"))));
            parallel_or_scale(&mut out);
            false_origin(&mut out);
        }
        _ => return None,
    }
    // The ellipsoid, where the definition names one CF can give.
    let ellipsoid = match (text("datum"), text("ellps")) {
        (Some("WGS84"), _) | (_, Some("WGS84")) => Some((6_378_137.0, 298.257_223_563)),
        (Some("NAD83"), _) | (_, Some("GRS80")) => Some((6_378_137.0, 298.257_222_101)),
        (_, Some("intl")) => Some((6_378_388.0, 297.0)),
        (_, Some("bessel")) => Some((6_377_397.155, 299.152_812_8)),
        (_, Some("krass")) => Some((6_378_245.0, 298.3)),
        (Some("NAD27"), _) | (_, Some("clrk66")) => Some((6_378_206.4, 294.978_698_213_898)),
        (Some("OSGB36"), _) | (_, Some("airy")) => Some((6_377_563.396, 299.324_964_6)),
        _ => num("a").zip(num("rf")),
    };
    if let Some((a, rf)) = ellipsoid {
        out.push(("semi_major_axis", Number(a)));
        out.push(("inverse_flattening", Number(rf)));
    }
    Some(out)
}

/// Longitude and latitude (degrees, WGS 84) to UTM easting and northing
/// (metres) in `zone`: Krüger's series to the third order in the third
/// flattening (Karney 2011, eq. 7-9), within a millimetre inside a zone
/// and its neighbours' first degrees. One projection, for placing
/// observers given in longitude and latitude on a UTM DEM; terrabake does
/// not otherwise reproject.
pub(crate) fn lonlat_to_utm(lon: f64, lat: f64, (zone, south): (u32, bool)) -> (f64, f64) {
    const A: f64 = 6_378_137.0;
    const F: f64 = 1.0 / 298.257_223_563;
    const K0: f64 = 0.9996;
    let n = F / (2.0 - F);
    let big_a = A / (1.0 + n) * (1.0 + n * n / 4.0 + n.powi(4) / 64.0);
    let alpha = [
        n / 2.0 - 2.0 * n * n / 3.0 + 5.0 * n.powi(3) / 16.0,
        13.0 * n * n / 48.0 - 3.0 * n.powi(3) / 5.0,
        61.0 * n.powi(3) / 240.0,
    ];
    let (phi, dlam) = (
        lat.to_radians(),
        (lon - (f64::from(zone) * 6.0 - 183.0)).to_radians(),
    );
    let c = 2.0 * n.sqrt() / (1.0 + n);
    let t = (phi.sin().atanh() - c * (c * phi.sin()).atanh()).sinh();
    let xi = t.atan2(dlam.cos());
    let eta = (dlam.sin() / (1.0 + t * t).sqrt()).atanh();
    let (mut e, mut nn) = (eta, xi);
    for (j, a) in alpha.iter().enumerate() {
        let k = 2.0 * (j + 1) as f64;
        e += a * (k * xi).cos() * (k * eta).sinh();
        nn += a * (k * xi).sin() * (k * eta).cosh();
    }
    let false_north = if south { 10_000_000.0 } else { 0.0 };
    (500_000.0 + K0 * big_a * e, false_north + K0 * big_a * nn)
}

/// A GeoKey directory for a local metric grid with no named CRS (synthetic
/// terrains): projected, user-defined, metres.
pub(crate) fn local_metric_keys(raster_type: RasterType) -> Vec<u16> {
    let rt = match raster_type {
        RasterType::Area => 1,
        RasterType::Point => 2,
    };
    vec![
        1,
        1,
        0,
        4, //
        GT_MODEL_TYPE,
        0,
        1,
        1, //
        GT_RASTER_TYPE,
        0,
        1,
        rt, //
        PROJECTED_CS_TYPE,
        0,
        1,
        32767, //
        PROJ_LINEAR_UNITS,
        0,
        1,
        9001,
    ]
}

#[cfg(test)]
mod tests {
    use super::CfValue::{Number, Numbers, Text};

    #[test]
    fn cf_grid_mappings_of_common_epsg_codes() {
        let get = |epsg, key| {
            super::cf_grid_mapping(epsg)
                .unwrap()
                .into_iter()
                .find(|(k, _)| *k == key)
                .map(|(_, v)| v)
        };
        assert_eq!(
            get(4326, "grid_mapping_name"),
            Some(Text("latitude_longitude"))
        );
        assert_eq!(
            get(4326, "inverse_flattening"),
            Some(Number(298.257_223_563))
        );
        assert_eq!(
            get(32630, "grid_mapping_name"),
            Some(Text("transverse_mercator"))
        );
        assert_eq!(
            get(32630, "longitude_of_central_meridian"),
            Some(Number(-3.0))
        );
        assert_eq!(get(32733, "false_northing"), Some(Number(1e7)));
        assert_eq!(
            get(3413, "grid_mapping_name"),
            Some(Text("polar_stereographic"))
        );
        assert_eq!(
            get(3413, "straight_vertical_longitude_from_pole"),
            Some(Number(-45.0))
        );
        assert_eq!(get(3413, "standard_parallel"), Some(Number(70.0)));
        assert_eq!(
            get(3035, "grid_mapping_name"),
            Some(Text("lambert_azimuthal_equal_area"))
        );
        assert_eq!(get(3035, "false_easting"), Some(Number(4_321_000.0)));
        assert_eq!(get(3035, "semi_major_axis"), Some(Number(6_378_137.0)));
        assert_eq!(
            get(2154, "standard_parallel"),
            Some(Numbers(vec![49.0, 44.0]))
        );
    }

    use super::*;

    #[test]
    fn geographic_spacing_at_equator_and_60_degrees() {
        let mut g = georef_from_keys(
            vec![1, 1, 0, 1, GT_MODEL_TYPE, 0, 1, 2],
            vec![],
            String::new(),
            [0.0, 1.0 / 1200.0, 0.0, 0.5, 0.0, -1.0 / 1200.0],
        );
        // 1200 rows of 1/1200 degree from 0.5 N: centre row at 0.0 N.
        let c = cell_size(&g, 1200, 1.0);
        assert!((c.dx - 92.77).abs() < 0.05, "{}", c.dx);
        assert!((c.dy - 92.13).abs() < 0.05, "{}", c.dy);
        g.geotransform[3] = 60.5;
        let c = cell_size(&g, 1200, 1.0);
        assert!((c.dx - 46.50).abs() < 0.05, "{}", c.dx);
        // Per row (posts at cell centres, half a cell in): about 60.5 N at
        // the top, 59.5 N at the bottom, 1 at the centre row.
        let s = row_scale(Some(&g), 1200);
        assert_eq!(s.len(), 2399);
        assert_eq!(s[1200], 1.0);
        let half: f64 = 0.5 / 1200.0;
        let ratio = |lat: f64| lat.to_radians().cos() / (60.0f64 - half).to_radians().cos();
        assert!((s[0] - ratio(60.5 - half)).abs() < 1e-4, "{}", s[0]);
        assert!((s[2398] - ratio(59.5 + half)).abs() < 1e-4, "{}", s[2398]);
        assert!(row_scale(None, 10).is_empty());
    }

    #[test]
    fn utm_agrees_with_proj_to_a_millimetre() {
        // gdaltransform -s_srs EPSG:4326 -t_srs EPSG:326zz/327zz (PROJ 9).
        for (lon, lat, epsg, e, n) in [
            (-5.5, 7.5, 32630, 224_091.647_128_896, 829_808.794_871_788),
            (-5.25, 7.75, 32630, 251_841.241_006_499, 857_317.456_555_568),
            (
                -73.98,
                -40.5,
                32718,
                586_429.257_794_364,
                5_516_245.604_644_61,
            ),
            (9.9, 60.2, 32632, 549_895.568_472_582, 6_674_025.143_608_15),
            (-3.0, 7.9, 32630, 500_000.0, 873_242.723_060_886),
        ] {
            let (x, y) = lonlat_to_utm(lon, lat, utm_zone(epsg).unwrap());
            assert!(
                (x - e).abs() < 1e-3 && (y - n).abs() < 1e-3,
                "{lon},{lat}: {x},{y}"
            );
        }
        assert_eq!(utm_zone(4326), None);
    }

    #[test]
    fn keys_are_read_back() {
        let keys = local_metric_keys(RasterType::Point);
        assert_eq!(geo_key(&keys, GT_RASTER_TYPE), Some(2));
        assert_eq!(geo_key(&keys, PROJ_LINEAR_UNITS), Some(9001));
        assert_eq!(geo_key(&keys, 9999), None);
        assert_eq!(
            geo_key(&[1, 1, 0, 9], GT_MODEL_TYPE),
            None,
            "truncated directory"
        );
    }
}
