//! A horizon layer's features (`terrabake_format::features`) as a user
//! meets them: baked by `terrabake horizons --features N`, served by the
//! loader between bands against an exact dense reference, the same by
//! every reader (one post at a time, a row at a time, the GRASS files),
//! kept by a partitioned bake, refused where they cannot be served, and
//! checked when a manifest lists them.

mod common;

use std::path::Path;

use common::{fixture, stderr, stdout, terrabake};
use terrabake_format::horizons::HorizonMap;
use terrabake_format::Asset;

/// The 64 x 48 spike plain (one 1000 m post) as a GeoTIFF in `dir`.
fn spike_tif(dir: &Path) -> std::path::PathBuf {
    let tif = dir.join("spike.tif");
    if !tif.exists() {
        let o = terrabake(&[
            "synth",
            "spike",
            "--size",
            "64x48",
            "-o",
            tif.to_str().unwrap(),
            "-q",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    tif
}

/// [`spike_tif`] ingested at `dir/NAME`.
fn spike_plain(dir: &Path, name: &str) -> String {
    let tif = spike_tif(dir);
    let asset = dir.join(name);
    let o = terrabake(&[
        "ingest",
        tif.to_str().unwrap(),
        "-o",
        asset.to_str().unwrap(),
        "-q",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    asset.to_str().unwrap().to_owned()
}

/// 32 directions lose the spike between bands by tens of degrees; with it
/// listed, the largest error at every post whose horizon the DEM's edge
/// cannot cut is what the bands make of the plain (none: the spike's own
/// post, whose horizon is the plain's far edge, is one the edge may cut),
/// and the bands themselves keep their values.
#[test]
fn a_listed_spike_is_served_exactly_between_bands() {
    let dir = tempfile::tempdir().unwrap();
    let (bare, listed) = (
        spike_plain(dir.path(), "bare.tbake"),
        spike_plain(dir.path(), "listed.tbake"),
    );
    for (asset, features) in [(&bare, "0"), (&listed, "4")] {
        let o = terrabake(&[
            "horizons",
            asset,
            "--sectors",
            "32",
            "--features",
            features,
            "-q",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let largest = |asset: &str| common::largest_dense_error(Path::new(asset), 1440).0;
    let (without, with) = (largest(&bare), largest(&listed));
    eprintln!("spike plain, 32 directions: largest error {without:.3} deg bare, {with:.3} with the spike listed");
    assert!(without > 20.0, "the bands alone lose the spike: {without}");
    assert!(with < 3.0, "the listed spike is served: {with}");

    // Only posts that rise above all eight neighbours are listed: the
    // plain has one, whatever was asked.
    let opened = Asset::open(&listed).unwrap();
    let map = HorizonMap::open(&opened).unwrap();
    let features = map.features().expect("features listed");
    assert_eq!(features.posts.len(), 1);
    assert_eq!((features.posts[0].x, features.posts[0].y), (32, 24));
    // The bands are the same bits as a bake without features.
    let bare_opened = Asset::open(&bare).unwrap();
    let (a, b) = (
        opened.layer("horizon", 0).unwrap(),
        bare_opened.layer("horizon", 0).unwrap(),
    );
    for band in 0..a.bands() {
        let mut rows = [vec![0f32; 64 * 48], vec![0f32; 64 * 48]];
        a.read_rows_f32(band, 0, &mut rows[0]).unwrap();
        b.read_rows_f32(band, 0, &mut rows[1]).unwrap();
        assert!(rows[0]
            .iter()
            .zip(&rows[1])
            .all(|(x, y)| x.to_bits() == y.to_bits()));
    }
    // A row at a time (sun shading, the GRASS files, the correction
    // factor) serves what one post at a time does.
    for azimuth in [0.0, 41.3, 200.0, 333.3] {
        let mut rows = vec![0f32; 64 * 48];
        map.served_rows(azimuth, 0, &mut rows).unwrap();
        for (k, &v) in rows.iter().enumerate() {
            let one = map
                .horizon_at((k % 64) as u32, (k / 64) as u32, azimuth)
                .unwrap()
                .unwrap();
            assert_eq!(v, one as f32, "post {k}, azimuth {azimuth}");
        }
    }
    // What people read: `info` names them, `horizons --json` counts them.
    let info = stdout(&terrabake(&["info", &listed]));
    assert!(
        info.contains("features: 1 post served exactly between bands"),
        "{info}"
    );
    let o = terrabake(&[
        "horizons",
        &listed,
        "--sectors",
        "32",
        "--features",
        "4",
        "--json",
        "-q",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(json["horizon"]["features"], 1, "{json}");
}

/// The GRASS `r.horizon` files are read between bands, so they carry the
/// features: at compass 35 degrees (GRASS 55), between two of 8 bands, the
/// spike stands over a post 10 rows south and 7 columns west of it that
/// the bands alone leave open, and every post of the file is what the
/// loader serves (radians, negatives as 0).
#[test]
fn grass_files_carry_the_listed_spikes() {
    let dir = tempfile::tempdir().unwrap();
    let asset = spike_plain(dir.path(), "spike.tbake");
    let o = terrabake(&[
        "horizons",
        &asset,
        "--sectors",
        "8",
        "--features",
        "1",
        "-q",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = dir.path().join("grass");
    let o = terrabake(&[
        "export",
        &asset,
        "--layer",
        "horizon",
        "--for",
        "grass",
        "-o",
        out.to_str().unwrap(),
        "--step",
        "5",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let opened = Asset::open(&asset).unwrap();
    let map = HorizonMap::open(&opened).unwrap();
    let mut d =
        tiff::decoder::Decoder::new(std::fs::File::open(out.join("horizon_055.tif")).unwrap())
            .unwrap();
    let (cw, _) = d.chunk_data_dimensions(0);
    let tiff::decoder::DecodingResult::F32(v) = d.read_chunk(0).unwrap() else {
        panic!("f32 tiles")
    };
    for y in 0..48u32 {
        for x in 0..64u32 {
            let got = v[(y * cw + x) as usize];
            let want = map
                .horizon_at(x, y, 35.0)
                .unwrap()
                .unwrap()
                .max(0.0)
                .to_radians() as f32;
            assert!(
                (got - want).abs() < 1e-6,
                "post ({x}, {y}): {got} vs {want}"
            );
        }
    }
    let spike = map.horizon_at(25, 34, 35.0).unwrap().unwrap();
    let (i, j) = (0, 1); // bands at 0 and 45 degrees
    let bands = [
        map.angle(25, 34, i).unwrap().unwrap(),
        map.angle(25, 34, j).unwrap().unwrap(),
    ];
    assert!(
        spike > 50.0 && bands.iter().all(|&b| b < 1.0),
        "{spike} {bands:?}"
    );
}

/// Partitioned by bands, every part lists the same features (found over
/// the whole DEM), and the join keeps them.
#[test]
fn a_partitioned_bake_keeps_the_features() {
    let dir = tempfile::tempdir().unwrap();
    let tif = spike_tif(dir.path());
    let recipe = dir.path().join("r.toml");
    std::fs::write(
        &recipe,
        "[[stage]]\nname = \"horizons\"\nsectors = 16\nfeatures = 2\n",
    )
    .unwrap();
    let (whole, parted) = (
        dir.path().join("whole.tbake"),
        dir.path().join("parted.tbake"),
    );
    let (t, r) = (tif.to_str().unwrap(), recipe.to_str().unwrap());
    let o = terrabake(&[
        "bake",
        t,
        "-o",
        whole.to_str().unwrap(),
        "--recipe",
        r,
        "-q",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for part in 0..2 {
        let o = terrabake(&[
            "bake",
            t,
            "-o",
            parted.to_str().unwrap(),
            "--recipe",
            r,
            "--parts",
            "2",
            "--part",
            &part.to_string(),
            "-q",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let o = terrabake(&["assemble", parted.to_str().unwrap(), "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let features = |asset: &Path| {
        let a = Asset::open(asset).unwrap();
        a.layer("horizon", 0).unwrap().entry().features.clone()
    };
    assert!(features(&whole).is_some());
    assert_eq!(features(&whole), features(&parted));
    let o = terrabake(&[
        "verify",
        parted.to_str().unwrap(),
        "--same-as",
        whole.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// Where features cannot be served the stage says so before any work: on
/// a latitude/longitude grid, with another method, beyond the most a
/// layer lists; and a manifest listing features off the grid is refused
/// when the asset is opened.
#[test]
fn features_are_refused_where_they_cannot_be_served() {
    let dir = tempfile::tempdir().unwrap();
    let geographic = dir.path().join("geo.tbake");
    let src = fixture("tiff/int16_nodata_geographic.tif");
    let o = terrabake(&[
        "ingest",
        src.to_str().unwrap(),
        "-o",
        geographic.to_str().unwrap(),
        "-q",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let g = geographic.to_str().unwrap();
    let o = terrabake(&["horizons", g, "--features", "8", "-q"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("latitude/longitude"), "{}", stderr(&o));
    assert!(
        Asset::open(g).unwrap().layer("horizon", 0).is_err(),
        "nothing half-baked is left"
    );

    let plain = spike_plain(dir.path(), "plain.tbake");
    for (flags, says) in [
        (
            &["--method", "sector", "--features", "4"][..],
            "line directions only",
        ),
        (&["--features", "5000"][..], "at most 4096"),
        (&["--feature-rise", "3"][..], "--features"),
    ] {
        let mut args = vec!["horizons", &plain];
        args.extend_from_slice(flags);
        let o = terrabake(&args);
        assert!(!o.status.success(), "{flags:?}");
        assert!(stderr(&o).contains(says), "{flags:?}: {}", stderr(&o));
    }

    // A listed post on the DEM's edge: the manifest is refused, naming it.
    let o = terrabake(&["horizons", &plain, "--features", "1", "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let path = Path::new(&plain).join("manifest.tba");
    let bytes = std::fs::read(&path).unwrap();
    let mut json: serde_json::Value = serde_json::from_slice(&bytes[32..]).unwrap();
    for layer in json["layers"].as_array_mut().unwrap() {
        if layer["name"] == "horizon" {
            layer["features"]["posts"][0]["x"] = 0.into();
        }
    }
    let manifest: terrabake_format::Manifest = serde_json::from_value(json).unwrap();
    let err = manifest.validate().unwrap_err();
    assert!(err.contains("feature post (0, 24)"), "{err}");
}
