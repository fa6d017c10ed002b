//! Shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use terrabake_format::{Asset, Mmap};

pub const FIXTURE_W: u32 = 70;
pub const FIXTURE_H: u32 = 45;

/// The formula every TIFF fixture holds (twin of `expected` in
/// tests/fixtures/make_tiff_fixtures.py), as the f32 height terrabake stores.
pub fn fixture_value(sample_type: &str, x: u32, y: u32) -> f32 {
    let (x, y) = (i64::from(x), i64::from(y));
    let v = match sample_type {
        "int8" => ((x * 7 + y * 13) % 256 - 128) as f64,
        "uint8" => ((x * 7 + y * 13) % 256) as f64,
        "int16" => ((x * 389 + y * 1031) % 65536 - 32768) as f64,
        "uint16" => ((x * 389 + y * 1031) % 65536) as f64,
        "int32" => (x * 10007 + y * 70001 - 2_000_000) as f64,
        "uint32" => (x * 10007 + y * 70001 + 10000) as f64,
        "float32" => (x * 37 + y * 101 - 2000) as f64 / 8.0,
        "float64" => (x * 37 + y * 101 - 2000) as f64 / 1024.0,
        other => panic!("no formula for {other}"),
    };
    v as f32
}

pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

pub fn repo_file(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(name)
}

/// Every post of an asset's height layer, row-major.
pub fn heights(asset: &Asset<Mmap>) -> Vec<f32> {
    let layer = asset.height().expect("height layer");
    let mut out = vec![0f32; layer.width() as usize * layer.height() as usize];
    layer
        .read_window(0, 0, 0, layer.width(), layer.height(), &mut out)
        .expect("read");
    out
}

/// Runs the terrabake binary.
pub fn terrabake(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_terrabake"))
        .args(args)
        .output()
        .expect("run terrabake")
}

/// Runs the terrabake binary with the environment variable `var` set to
/// `value`, or removed where `None`.
pub fn terrabake_with(var: (&str, Option<&std::ffi::OsStr>), args: &[&str]) -> Output {
    terrabake_with_all(&[var], args)
}

/// [`terrabake_with`] for several variables.
pub fn terrabake_with_all(vars: &[(&str, Option<&std::ffi::OsStr>)], args: &[&str]) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_terrabake"));
    for &(var, value) in vars {
        match value {
            Some(value) => command.env(var, value),
            None => command.env_remove(var),
        };
    }
    command.args(args).output().expect("run terrabake")
}

/// Makes a FIFO at `path`: what a reader must refuse rather than wait on.
pub fn mkfifo(path: &std::path::Path) {
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Bitwise equality that treats every NaN as equal (nodata).
pub fn same_heights(a: f32, b: f32) -> bool {
    (a.is_nan() && b.is_nan()) || a.to_bits() == b.to_bits()
}

/// A synthetic terrain ingested with tiles of `tile` and its pyramid built:
/// the asset directory `dir/t.tbake`.
pub fn synth_with_pyramid(
    dir: &Path,
    kind: terrabake::io::synth::SynthKind,
    w: u32,
    h: u32,
    seed: u64,
    opts: terrabake::stages::ingest::IngestOptions,
) -> PathBuf {
    use terrabake::plumbing::progress::Progress;
    let tif = dir.join("t.tif");
    terrabake::io::synth::write_geotiff(&tif, kind, w, h, seed, Progress::hidden()).unwrap();
    let out = dir.join("t.tbake");
    terrabake::stages::ingest::ingest(&tif, &out, &opts, Progress::hidden()).unwrap();
    terrabake::stage::run_stage(
        &out,
        &terrabake::stages::pyramid::PyramidStage,
        false,
        Progress::hidden(),
    )
    .unwrap();
    out
}

/// A `w x h` window at `(x0, y0)` of the bundled SRTM tile, with the tile's
/// post spacing in metres.
pub fn srtm_crop((x0, y0): (u32, u32), (w, h): (u32, u32)) -> (Vec<f32>, f64, f64) {
    let dir = tempfile::tempdir().expect("temp dir");
    let full = dir.path().join("srtm.tbake");
    terrabake::stages::ingest::ingest(
        &repo_file("data/srtm3_n07w006_geographic_int16.tif"),
        &full,
        &terrabake::stages::ingest::IngestOptions::default(),
        terrabake::plumbing::progress::Progress::hidden(),
    )
    .expect("ingest the bundled tile");
    let srtm = Asset::open(&full).expect("open");
    let mut crop = vec![0f32; (w * h) as usize];
    srtm.height()
        .expect("height")
        .read_window(0, x0, y0, w, h, &mut crop)
        .expect("read");
    let cs = &srtm.manifest().cell_size;
    (crop, cs.dx, cs.dy)
}

/// The largest error of an asset's served horizon (`HorizonMap::served_at`)
/// at every post, against exact line horizons in `directions` directions
/// (grid steps within a fifth of their spacing of `i * 360 / directions`:
/// between the stored bands too, with at least twice as many), leaving out
/// the samples at the DEM's edge as `check` does: where nothing lies ahead,
/// where the edge may cut the exact horizon (terrain beyond the edge, as
/// high as the DEM's highest post, could rise above it), and where it may
/// cut a serving band before the distance within which the exact horizon
/// is set; and the post and azimuth where it is.
pub fn largest_dense_error(asset: &Path, directions: usize) -> (f64, (usize, usize), f64) {
    use terrabake::algorithms::horizon::{brute, plan_bands, BandKind, Method};
    use terrabake::plan::reference::edge_made_error;
    use terrabake::stages::horizons::HorizonsStage;
    use terrabake::terrain::held::HeldDem;
    use terrabake_format::horizons::{bands_around, edge_distance, HorizonMap, NOTHING_AHEAD};

    let opened = Asset::open(asset).unwrap();
    let map = HorizonMap::open(&opened).unwrap();
    let stage = HorizonsStage::recorded(&opened).unwrap();
    let dem = HeldDem::read(&opened).unwrap();
    let t = dem.terrain(stage.sight.curvature_coefficient(opened.manifest()));
    let m = opened.manifest();
    assert!(
        directions >= 2 * map.azimuths().len(),
        "a reference between the bands"
    );
    let dense = plan_bands(
        Method::Line,
        directions,
        m.cell_size.dx,
        m.cell_size.dy,
        Some(72.0 / directions as f64),
    );
    let top =
        t.z.iter()
            .copied()
            .filter(|z| !z.is_nan())
            .fold(f32::MIN, f32::max);
    let mut largest = (0.0f64, (0, 0), 0.0);
    for row in 0..t.height {
        for col in 0..t.width {
            for band in &dense {
                let BandKind::Line(direction) = &band.kind else {
                    unreachable!("line bands")
                };
                let truth = f64::from(brute::line_horizon(&t, (col, row), direction.step, None));
                let served = map
                    .served_at(col as u32, row as u32, band.azimuth)
                    .unwrap()
                    .unwrap();
                if served.at_edge || truth == NOTHING_AHEAD {
                    continue;
                }
                let error = (served.angle - truth).abs();
                if error <= largest.0 {
                    continue;
                }
                let (i, j, _) = bands_around(map.azimuths(), band.azimuth);
                let angle = |k: usize| {
                    map.angle(col as u32, row as u32, k as u32)
                        .unwrap()
                        .unwrap()
                };
                let edge = |azimuth: f64| {
                    edge_distance(
                        (m.width, m.height),
                        (m.cell_size.dx, m.cell_size.dy),
                        (col as f64, row as f64),
                        azimuth,
                    )
                };
                let cut = edge_made_error(
                    (f64::from(top - t.at(col, row)), t.curvature),
                    edge,
                    (band.azimuth, truth),
                    [(map.azimuths()[i], angle(i)), (map.azimuths()[j], angle(j))],
                );
                if !cut {
                    largest = (error, (col, row), band.azimuth);
                }
            }
        }
    }
    largest
}
