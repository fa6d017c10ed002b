//! Every GeoTIFF variant the issue lists, made by GDAL (see
//! tests/fixtures/make_tiff_fixtures.py), read back bit-exact against the
//! formula the fixtures hold, with georeferencing and nodata.

mod common;

use common::*;
use terrabake::plumbing::progress::Progress;
use terrabake::stages::ingest::{ingest, IngestOptions};
use terrabake_format::manifest::{CrsKind, RasterType};
use terrabake_format::{Asset, Codec};

fn ingest_fixture(
    name: &str,
    opts: &IngestOptions,
) -> (tempfile::TempDir, Asset<terrabake_format::Mmap>) {
    let dir = tempfile::tempdir().unwrap();
    let asset_dir = dir.path().join("a.tbake");
    ingest(
        &fixture(&format!("tiff/{name}")),
        &asset_dir,
        opts,
        Progress::hidden(),
    )
    .unwrap_or_else(|e| panic!("{name}: {e:#}"));
    let asset = Asset::open(&asset_dir).unwrap();
    (dir, asset)
}

#[test]
fn every_variant_reads_back_bit_exact() {
    let files: Vec<String> = std::fs::read_dir(fixture("tiff"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.ends_with(".tif") && !n.contains("nodata") && !n.contains("sparse"))
        .collect();
    assert!(files.len() >= 28, "fixtures missing: {files:?}");
    for name in files {
        let sample_type = name.split('_').next().unwrap();
        for opts in [
            IngestOptions {
                tile_size: 16,
                ..Default::default()
            },
            IngestOptions {
                tile_size: 32,
                codec: Codec::Zstd,
                ..Default::default()
            },
        ] {
            let (_dir, asset) = ingest_fixture(&name, &opts);
            let m = asset.manifest();
            assert_eq!((m.width, m.height), (FIXTURE_W, FIXTURE_H), "{name}");
            assert_eq!(m.nodata.count, 0, "{name}");
            let got = heights(&asset);
            for y in 0..FIXTURE_H {
                for x in 0..FIXTURE_W {
                    let want = fixture_value(sample_type, x, y);
                    let have = got[(y * FIXTURE_W + x) as usize];
                    assert!(
                        same_heights(want, have),
                        "{name} ({x}, {y}): want {want}, have {have}"
                    );
                }
            }
            // Projected UTM 30N, 90 m, as the generator set it.
            let g = m.georef.as_ref().expect("georef");
            assert_eq!(g.crs_kind, CrsKind::Projected, "{name}");
            assert_eq!(g.epsg, Some(32630), "{name}");
            assert_eq!(g.raster_type, RasterType::Area);
            assert_eq!(
                g.geotransform,
                [500000.0, 90.0, 0.0, 900000.0, 0.0, -90.0],
                "{name}"
            );
            assert_eq!((m.cell_size.dx, m.cell_size.dy), (90.0, 90.0));
            assert!(asset.verify().problems.is_empty());
        }
    }
}

fn in_holes(x: u32, y: u32) -> bool {
    (10..13).contains(&y) || ((30..40).contains(&y) && (40..50).contains(&x))
}

#[test]
fn nodata_values_nan_and_float_min_become_nodata() {
    for (name, source_value, sample_type) in [
        (
            "float32_nodata_min.tif",
            "-3.4028234663852886e+38",
            "float32",
        ),
        ("float32_nodata_nan.tif", "nan", "float32"),
        ("int16_nodata_geographic.tif", "-32767", "int16"),
    ] {
        let (_dir, asset) = ingest_fixture(
            name,
            &IngestOptions {
                tile_size: 16,
                ..Default::default()
            },
        );
        let m = asset.manifest();
        let holes = (0..FIXTURE_H)
            .flat_map(|y| (0..FIXTURE_W).map(move |x| (x, y)))
            .filter(|&(x, y)| in_holes(x, y))
            .count();
        assert_eq!(m.nodata.count, holes as u64, "{name}");
        assert_eq!(
            m.nodata
                .source_value
                .as_deref()
                .map(|s| s.to_ascii_lowercase()),
            Some(source_value.to_ascii_lowercase()),
            "{name}"
        );
        let got = heights(&asset);
        for y in 0..FIXTURE_H {
            for x in 0..FIXTURE_W {
                let have = got[(y * FIXTURE_W + x) as usize];
                if in_holes(x, y) {
                    assert!(
                        have.is_nan(),
                        "{name} ({x}, {y}) should be nodata, is {have}"
                    );
                    assert_eq!(asset.height().unwrap().height_at(x, y).unwrap(), None);
                } else {
                    assert_eq!(have, fixture_value(sample_type, x, y), "{name} ({x}, {y})");
                }
            }
        }
        let r = m.height_range.unwrap();
        assert!(
            r.min > -1e6 && r.max < 1e6,
            "{name}: nodata leaked into the range {r:?}"
        );
    }
}

#[test]
fn geographic_grid_gets_metric_cell_size() {
    let (_dir, asset) = ingest_fixture("int16_nodata_geographic.tif", &IngestOptions::default());
    let m = asset.manifest();
    let g = m.georef.as_ref().unwrap();
    assert_eq!(g.crs_kind, CrsKind::Geographic);
    assert_eq!(g.epsg, Some(4326));
    // 3 arc-seconds near 8 N: about 91.8 m east-west and 92.1 m north-south.
    assert!((m.cell_size.dx - 91.8).abs() < 0.2, "{}", m.cell_size.dx);
    assert!((m.cell_size.dy - 92.1).abs() < 0.2, "{}", m.cell_size.dy);
    assert_eq!(m.cell_size.source, "geographic-centre");
}

#[test]
fn sparse_tiles_are_nodata() {
    let (_dir, asset) = ingest_fixture(
        "float32_sparse.tif",
        &IngestOptions {
            tile_size: 16,
            ..Default::default()
        },
    );
    let got = heights(&asset);
    let mut holes = 0;
    for y in 0..FIXTURE_H {
        for x in 0..FIXTURE_W {
            let sparse = ((0..16).contains(&y) && (16..32).contains(&x))
                || ((32..45).contains(&y) && (48..64).contains(&x));
            let have = got[(y * FIXTURE_W + x) as usize];
            if sparse {
                holes += 1;
                assert!(have.is_nan(), "({x}, {y}) {have}");
            } else {
                assert_eq!(have, fixture_value("float32", x, y));
            }
        }
    }
    assert_eq!(asset.manifest().nodata.count, holes);
    // The all-nodata tile of the asset (x 16..32, y 0..16) is a constant chunk.
    assert!(asset.manifest().layers[0].constant_chunks >= 1);
}

#[test]
fn bundled_srtm_tile() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("srtm.tbake");
    let m = ingest(
        &repo_file("data/srtm3_n07w006_geographic_int16.tif"),
        &out,
        &IngestOptions::default(),
        Progress::hidden(),
    )
    .unwrap();
    assert_eq!((m.width, m.height), (1201, 1201));
    let r = m.height_range.unwrap();
    assert_eq!((r.min, r.max), (145.0, 546.0));
    let g = m.georef.as_ref().unwrap();
    assert_eq!(g.raster_type, RasterType::Point);
    // The south-west post sits exactly on 7 N, 6 W.
    let (lon, lat) = g.post_to_world(0.0, 1200.0);
    assert!(
        (lon + 6.0).abs() < 1e-9 && (lat - 7.0).abs() < 1e-9,
        "{lon} {lat}"
    );
}
