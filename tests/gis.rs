//! What GIS users get out: `terrabake profile` (the exact horizon at any
//! azimuth of one point) against the line sweep and a dense sampling of
//! the sight line; `export --for grass` named and valued as `r.horizon`'s
//! files; the COG writer's layout read back by an independent TIFF reader;
//! the Zarr export read back by a reader written here from the Zarr v3
//! spec (zarr-python and xarray read it in python/tests/test_zarr_export.py).
//! GDAL's own validator runs in python/tests (pipelines/python/test.sh) and
//! `r.sun` on the GRASS export in pipelines/gis/check_grass.sh.

mod common;

use common::{stderr, stdout, terrabake};
use terrabake::algorithms::horizon::{brute, line, plan_bands, BandKind, Method};
use terrabake::io::synth::{self, SynthKind};
use terrabake::terrain::Terrain;

fn grid(kind: SynthKind, w: usize, h: usize, seed: u64) -> Vec<f32> {
    let mut z = vec![0f32; w * h];
    synth::fill_rows(kind, 0, &mut z, w as u32, h as u32, seed);
    z
}

/// At a line band's own azimuth, the profile's sight line is the band's
/// line: the same horizon as the sweep, at every post.
#[test]
fn profile_at_a_band_azimuth_is_the_line_method() {
    let (w, h) = (41, 37);
    for (kind, dx, dy) in [
        (SynthKind::Fractal, 30.0, 30.0),
        (SynthKind::Blocks, 20.0, 35.0),
    ] {
        let z = grid(kind, w, h, 3);
        let mut t = Terrain::new(&z, w, h, dx, dy);
        t.curvature = 1e-6;
        for band in plan_bands(Method::Line, 16, dx, dy, None) {
            let BandKind::Line(dir) = &band.kind else {
                unreachable!()
            };
            let mut sweep = vec![0f32; w * h];
            line::line_horizons(&t, dir, &mut sweep);
            for row in 0..h {
                for col in 0..w {
                    let records = brute::ray_horizon_records(&t, (col, row), band.azimuth);
                    let got = records.last().map_or(-90.0, |r| r.angle);
                    let want = sweep[row * w + col];
                    assert!(
                        (got - want).abs() < 2e-4,
                        "{kind:?} azimuth {} at ({col}, {row}): profile {got}, sweep {want}",
                        band.azimuth
                    );
                }
            }
        }
    }
}

/// At any azimuth, the exact horizon is the highest of the sight line's
/// points: no sample of the surface along the line rises above it, and
/// dense samples come within a hair of it; the distance is where it is met.
#[test]
fn profile_at_any_azimuth_bounds_a_dense_sampling() {
    let (w, h, dx, dy) = (48, 40, 25.0, 25.0);
    let z = grid(SynthKind::Fractal, w, h, 11);
    let t = Terrain::new(&z, w, h, dx, dy);
    let height = |x: f64, y: f64| -> f64 {
        // Two triangles per cell, split south-west to north-east.
        let (c, r) = (x.floor().min((w - 2) as f64), y.floor().min((h - 2) as f64));
        let (fx, fy) = (x - c, y - r);
        let at = |i: f64, j: f64| f64::from(z[(r + j) as usize * w + (c + i) as usize]);
        let (nw, ne, sw, se) = (at(0.0, 0.0), at(1.0, 0.0), at(0.0, 1.0), at(1.0, 1.0));
        // u east, v north from the south-west corner.
        let (u, v) = (fx, 1.0 - fy);
        if v >= u {
            sw + u * (ne - nw) + v * (nw - sw)
        } else {
            sw + u * (se - sw) + v * (ne - se)
        }
    };
    for (col, row) in [(24, 20), (5, 33), (40, 4)] {
        let zp = f64::from(z[row * w + col]);
        for i in 0..72 {
            let az = i as f64 * 5.0 + 1.7;
            let records = brute::ray_horizon_records(&t, (col, row), az);
            let Some(last) = records.last() else { continue };
            let (east, south) = (az.to_radians().sin(), -az.to_radians().cos());
            let mut best = f64::NEG_INFINITY;
            let mut s = 0.05;
            loop {
                let (x, y) = (col as f64 + east * s / dx, row as f64 + south * s / dy);
                if !(0.0..=(w - 1) as f64).contains(&x) || !(0.0..=(h - 1) as f64).contains(&y) {
                    break;
                }
                best = best.max(((height(x, y) - zp) / s).atan().to_degrees());
                s += 0.1;
            }
            let exact = f64::from(last.angle);
            assert!(
                best <= exact + 1e-4,
                "azimuth {az} at ({col}, {row}): a sample at {best} above the exact {exact}"
            );
            assert!(
                exact - best < 0.05,
                "azimuth {az} at ({col}, {row}): exact {exact}, samples reach {best}"
            );
            let (x, y) = (
                col as f64 + east * last.distance / dx,
                row as f64 + south * last.distance / dy,
            );
            let at_distance = ((height(x, y) - zp) / last.distance).atan().to_degrees();
            assert!(
                (at_distance - exact).abs() < 1e-3,
                "the horizon is met at its distance"
            );
        }
    }
}

/// The distance to the horizon is where the brute force meets it: the
/// last record of the post's sight line, on a fractal terrain with a hole
/// of nodata and the earth's curvature. (Where two points of a line were
/// exactly as steep, the sweep would keep the farther and the brute force
/// the nearer; this terrain has no such tie, so every post must agree.)
#[test]
fn horizon_distances_are_the_brute_forces() {
    let (w, h) = (45, 39);
    let mut z = grid(SynthKind::Fractal, w, h, 8);
    // A hole of nodata: lines cross it and posts beside it look over it.
    for r in 15..19 {
        for c in 20..23 {
            z[r * w + c] = f32::NAN;
        }
    }
    let mut t = Terrain::new(&z, w, h, 30.0, 25.0);
    t.curvature = 6.8e-8;
    let mut compared = 0;
    for band in plan_bands(Method::Line, 16, 30.0, 25.0, None) {
        let BandKind::Line(dir) = &band.kind else {
            unreachable!()
        };
        let mut sweep = line::BandedSweep::new(dir, (w, h), (30.0, 25.0), t.row_scale, true);
        let (mut angles, mut metres) = (vec![0f32; w * h], vec![0f32; w * h]);
        sweep.sweep_with_distances(&t, 0..h, &mut angles, Some(&mut metres));
        for row in 0..h {
            for col in 0..w {
                let d = f64::from(metres[row * w + col]);
                let records = brute::line_horizon_records(&t, (col, row), dir.step);
                match records.last() {
                    None => assert!(
                        d.is_nan(),
                        "({col}, {row}) {:?}: {d} m with no terrain ahead",
                        dir.step
                    ),
                    Some(last) => {
                        assert!(
                            (d - last.distance).abs() <= 1e-5 * last.distance,
                            "({col}, {row}) {:?}: sweep {d} m, brute force {} m",
                            dir.step,
                            last.distance
                        );
                        compared += 1;
                    }
                }
            }
        }
    }
    assert!(compared > 16 * (w * h - 12) * 9 / 10, "{compared} compared");
}

/// A fractal terrain with a hole of nodata, posts 30 x 25 m apart, with
/// the earth's curvature: what the distance tests run on.
fn holed_fractal(w: usize, h: usize) -> Vec<f32> {
    let mut z = grid(SynthKind::Fractal, w, h, 8);
    for r in h * 2 / 5..h / 2 {
        for c in w / 2..w / 2 + 3 {
            z[r * w + c] = f32::NAN;
        }
    }
    z
}

/// Whether a distance is the brute force's: both NaN where it found no
/// point, else within f32 rounding.
fn same_distance(got: f32, want: Option<f64>) -> bool {
    match want {
        None => got.is_nan(),
        Some(d) => (f64::from(got) - d).abs() <= 1e-5 * d.max(1.0),
    }
}

/// Stewart's tree with its points tagged by post, and the bounded scan,
/// name the post the brute force finds steepest in the wedge, at every
/// post, for every sector of 8 and a spread of 64 (with the IV-E check);
/// the tags leave the angles bit for bit as they are.
#[test]
fn sector_distances_are_the_brute_forces() {
    use terrabake::algorithms::horizon::sector::{self, NarrowStencil, SectorFrame};
    let (w, h) = (37, 33);
    let z = holed_fractal(w, h);
    let t = Terrain::new(&z, w, h, 30.0, 25.0).with_curvature(6.8e-8);
    for (count, step) in [(8, 1), (64, 9)] {
        let narrow = count == 64;
        for index in (0..count).step_by(step) {
            let frame = SectorFrame::new(index, count, t.dx, t.dy);
            let stencil = narrow.then(|| NarrowStencil::new(&frame, count, t.dx, t.dy));
            let mut plain = vec![0f32; w * h];
            sector::sector_horizons(&t, index, count, narrow, &mut plain);
            let (mut angles, mut metres) = (vec![0f32; w * h], vec![0f32; w * h]);
            sector::sector_horizons_with_distances(
                &t,
                (index, count),
                narrow,
                &mut angles,
                &mut metres,
            );
            assert!(
                angles
                    .iter()
                    .zip(&plain)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "sector {index}/{count}: the tags changed an angle"
            );
            let max = 260.0;
            let (mut near, mut near_metres) = (vec![0f32; w * h], vec![0f32; w * h]);
            sector::sector_horizons_within(
                &t,
                (index, count),
                narrow,
                max,
                [0..h, 0..w],
                &mut near,
                Some(&mut near_metres),
            );
            for i in 0..w * h {
                let post = (i % w, i / w);
                for (got, within) in [(metres[i], None), (near_metres[i], Some(max))] {
                    let want =
                        brute::sector_horizon_record(&t, post, &frame, stencil.as_ref(), within)
                            .map(|r| r.distance);
                    assert!(
                        same_distance(got, want),
                        "sector {index}/{count} within {within:?} at {post:?}: {got} m, brute force {want:?}"
                    );
                }
            }
        }
    }
}

/// The bounded line walk names the last point of the sight line's records
/// within the distance (the brute force's), and past the DEM the sweep's.
#[test]
fn bounded_line_distances_are_the_brute_forces() {
    let (w, h) = (37, 33);
    let z = holed_fractal(w, h);
    let t = Terrain::new(&z, w, h, 30.0, 25.0).with_curvature(6.8e-8);
    for band in plan_bands(Method::Line, 16, t.dx, t.dy, None) {
        let BandKind::Line(dir) = &band.kind else {
            unreachable!()
        };
        let stencil = line::Stencil::new(dir.step);
        let lengths = line::step_lengths(dir.step, h, (t.dx, t.dy), t.row_scale);
        let (mut swept, mut swept_metres) = (vec![0f32; w * h], vec![0f32; w * h]);
        line::line_horizons_with_distances(&t, dir, &mut swept, Some(&mut swept_metres));
        for (i, (&swept_angle, &swept_d)) in swept.iter().zip(&swept_metres).enumerate() {
            let post = (i % w, i / w);
            let records = brute::line_horizon_records(&t, post, dir.step);
            for max in [170.0, 1e9] {
                let (angle, got) = line::line_horizon_within::<Option<f64>>(
                    &t,
                    &stencil,
                    &lengths,
                    (post.0 as i64, post.1 as i64),
                    max,
                );
                let got = got.map_or(f32::NAN, |d| d as f32);
                let last = records.iter().take_while(|r| r.distance <= max).last();
                assert!(
                    same_distance(got, last.map(|r| r.distance)),
                    "{:?} within {max} m at {post:?}: {got} m, brute force {last:?}",
                    dir.step
                );
                if max == 1e9 && !angle.is_nan() {
                    assert!(
                        (got - swept_d).abs() <= 1e-4 * got.abs().max(1.0)
                            || (got.is_nan() && swept_d.is_nan()),
                        "{:?} at {post:?}: walk {got} m, sweep {swept_d} m",
                        dir.step,
                    );
                    assert!(
                        (angle - swept_angle).abs() < 1e-4,
                        "{:?} at {post:?}: walk {angle}, sweep {swept_angle}",
                        dir.step
                    );
                }
            }
        }
    }
}

/// On a plane with one spike, every method names the spike from the posts
/// that look at it along a grid axis: the spike's distance exactly.
#[test]
fn every_method_names_a_lone_spike() {
    use terrabake::algorithms::horizon::{band_horizons_into, BandOptions};
    let (w, h) = (30, 9);
    let mut z = vec![100f32; w * h];
    let spike = (25, 4);
    z[spike.1 * w + spike.0] = 400.0;
    let t = Terrain::new(&z, w, h, 20.0, 30.0);
    for method in [Method::Line, Method::Sector, Method::Sampled] {
        let east = plan_bands(method, 8, t.dx, t.dy, None)
            .into_iter()
            .find(|b| b.azimuth == 90.0)
            .unwrap();
        for max_distance in [None, Some(450.0)] {
            let opts = BandOptions {
                max_distance,
                ..BandOptions::default()
            };
            let (mut angles, mut metres) = (vec![0f32; w * h], vec![0f32; w * h]);
            band_horizons_into(
                &t,
                &east,
                opts,
                [0..h, 0..w],
                (&mut angles, Some(&mut metres)),
                Default::default(),
            );
            for col in 0..spike.0 {
                let want = (spike.0 - col) as f32 * 20.0;
                let got = metres[spike.1 * w + col];
                if max_distance.is_some_and(|m| f64::from(want) > m) {
                    assert!(got.is_nan() || got < want, "{method:?} at {col}: {got} m");
                } else {
                    assert_eq!(got, want, "{method:?} within {max_distance:?} at {col}");
                }
            }
            // Nothing lies east of the east edge.
            assert!(metres[spike.1 * w + w - 1].is_nan(), "{method:?}");
        }
    }
}

fn synth_asset(dir: &std::path::Path) -> std::path::PathBuf {
    let tif = dir.join("dem.tif");
    let asset = dir.join("dem.tbake");
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let o = terrabake(&["synth", "fractal", "--size", "60x44", "-o", &s(&tif), "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let recipe = dir.join("r.toml");
    std::fs::write(
        &recipe,
        "description = \"gis\"\n[[stage]]\nname = \"horizons\"\nsectors = 8\nmethod = \"sector\"\nencoding = \"f32\"\n",
    )
    .unwrap();
    let o = terrabake(&[
        "bake",
        &s(&tif),
        "-o",
        &s(&asset),
        "--recipe",
        &s(&recipe),
        "-q",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    asset
}

#[test]
fn profile_formats_and_refusals() {
    let dir = tempfile::tempdir().unwrap();
    let asset = synth_asset(dir.path());
    let a = asset.to_str().unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec!["profile", a, "--crs", "grid"];
        args.extend_from_slice(extra);
        terrabake(&args)
    };
    let o = run(&["--at", "30,20", "--step", "90"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = stdout(&o);
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines[0], "azimuth_deg,horizon_deg,distance_m");
    assert_eq!(lines.len(), 5);
    assert!(lines[2].starts_with("90,"));
    let o = run(&["--at", "30,20", "--step", "45", "--format", "json"]);
    let json: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(json["post"], serde_json::json!([30, 20]));
    assert_eq!(json["points"].as_array().unwrap().len(), 8);
    // PVGIS: from south, west positive; north (-180) first.
    let o = run(&["--at", "30,20", "--step", "90", "--format", "pvgis"]);
    let pv: Vec<String> = stdout(&o).lines().skip(1).map(String::from).collect();
    let azimuths: Vec<&str> = pv.iter().map(|l| l.split(' ').next().unwrap()).collect();
    assert_eq!(azimuths, ["-180", "-90", "0", "90"]);
    // The compass azimuth 90 (east) is PVGIS's -90.
    let east_csv = lines[2].split(',').nth(1).unwrap().parse::<f64>().unwrap();
    let east_pv = pv[1].split(' ').nth(1).unwrap().parse::<f64>().unwrap();
    assert!((east_csv - east_pv).abs() < 0.01);
    for (args, says) in [
        (
            &["--at", "300,20"][..],
            "--at 300,20 (--crs grid) is at post (300, 20), outside",
        ),
        (&["--at", "1,1", "--step", "0"][..], "--step"),
        (&["--at", "x,1"][..], "--at"),
    ] {
        let o = run(args);
        assert!(!o.status.success(), "{args:?}");
        assert!(stderr(&o).contains(says), "{args:?}: {}", stderr(&o));
    }
}

/// `profile --max-distance` looks as far as the bounded horizons stage: at
/// the axes, where a line band's grid direction is its azimuth, the
/// profile's horizon is the stage's stored angle (f32, curvature off), and
/// never farther out than the distance.
#[test]
fn profile_within_a_distance_is_the_bounded_line_stage() {
    let dir = tempfile::tempdir().unwrap();
    let asset = synth_asset(dir.path());
    let a = asset.to_str().unwrap();
    let limit = ["--max-distance", "240", "--curvature", "off"];
    let o = terrabake(
        &[
            &[
                "horizons",
                a,
                "--sectors",
                "4",
                "--encoding",
                "f32",
                "--no-sky",
                "--force",
                "-q",
            ][..],
            &limit,
        ]
        .concat(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let opened = terrabake_format::Asset::open(&asset).unwrap();
    let stored = terrabake_format::horizons::HorizonMap::open(&opened).unwrap();
    let mut cut = 0;
    for (col, row) in [(30, 20), (5, 40), (55, 3), (12, 12)] {
        let at = format!("{col},{row}");
        let args = [
            &[
                "profile", a, "--crs", "grid", "--at", &at, "--step", "90", "--format", "json",
            ][..],
            &limit,
        ]
        .concat();
        let o = terrabake(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let whole = terrabake(&[
            "profile",
            a,
            "--crs",
            "grid",
            "--at",
            &at,
            "--step",
            "90",
            "--format",
            "json",
            "--curvature",
            "off",
        ]);
        let json: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
        let whole: serde_json::Value = serde_json::from_str(&stdout(&whole)).unwrap();
        for (band, (p, q)) in json["points"]
            .as_array()
            .unwrap()
            .iter()
            .zip(whole["points"].as_array().unwrap())
            .enumerate()
        {
            let got = p["horizon_deg"].as_f64().unwrap();
            let want = stored
                .angle(col, row, band as u32)
                .unwrap()
                .expect("a post of the synthetic DEM");
            assert!(
                (got - want).abs() < 1e-4,
                "({col}, {row}) band {band}: profile {got}, stage {want}"
            );
            if let Some(d) = p["distance_m"].as_f64() {
                assert!(d <= 240.0, "({col}, {row}) band {band}: {d} m");
            }
            cut += usize::from(q["distance_m"].as_f64().is_some_and(|d| d > 240.0));
        }
    }
    assert!(
        cut > 0,
        "no whole-DEM horizon lay beyond the distance: the test cuts nothing"
    );
}

/// r.horizon's files: one per direction, counter-clockwise from east,
/// radians; a direction on a stored (sector) band carries it exactly, but
/// for a negative angle, written as 0 (r.sun's unsigned bytes would wrap it
/// to a horizon near the zenith).
#[test]
fn grass_export_names_directions_as_r_horizon_does() {
    let dir = tempfile::tempdir().unwrap();
    let asset = synth_asset(dir.path());
    let out = dir.path().join("grass");
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let o = terrabake(&[
        "export",
        &s(&asset),
        "--layer",
        "horizon",
        "--for",
        "grass",
        "-o",
        &s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("horizon_step=45"), "{}", stderr(&o));
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "horizon_000.tif",
            "horizon_045.tif",
            "horizon_090.tif",
            "horizon_135.tif",
            "horizon_180.tif",
            "horizon_225.tif",
            "horizon_270.tif",
            "horizon_315.tif"
        ]
    );
    let opened = terrabake_format::Asset::open(&asset).unwrap();
    let layer = opened.layer("horizon", 0).unwrap();
    // GRASS 90 (north) is compass 0, band 0; GRASS 0 (east) is compass 90, band 2.
    let mut negative = 0;
    for (file, band) in [
        ("horizon_090.tif", 0),
        ("horizon_000.tif", 2),
        ("horizon_135.tif", 7),
    ] {
        let mut d =
            tiff::decoder::Decoder::new(std::fs::File::open(out.join(file)).unwrap()).unwrap();
        assert_eq!(d.dimensions().unwrap(), (60, 44));
        let (cw, _) = d.chunk_data_dimensions(0);
        let tiff::decoder::DecodingResult::F32(v) = d.read_chunk(0).unwrap() else {
            panic!()
        };
        let mut want = vec![0f32; 60 * 44];
        layer.read_rows_f32(band, 0, &mut want).unwrap();
        for (i, w) in want.iter().enumerate() {
            let got = v[(i / 60) * cw as usize + i % 60];
            let clamped = if *w < 0.0 { 0.0 } else { w.to_radians() };
            assert!(
                (got.is_nan() && w.is_nan()) || got == clamped,
                "{file} post {i}: {got} vs {w}"
            );
        }
        negative += want.iter().filter(|w| **w < 0.0).count();
    }
    assert!(
        negative > 0,
        "the synthetic terrain has no negative horizon to clamp"
    );
    let o = terrabake(&["export", &s(&asset), "--for", "grass", "-o", &s(&out)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--layer horizon"));
}

/// `--distance` writes `horizon_distance` for every method, bounded or
/// not, one band per azimuth beside the angles.
#[test]
fn every_method_writes_distances() {
    let dir = tempfile::tempdir().unwrap();
    let asset = synth_asset(dir.path());
    for extra in [
        &["--method", "sector"][..],
        &["--method", "sector", "--max-distance", "500"][..],
        &["--max-distance", "500"][..],
        &["--method", "sampled"][..],
    ] {
        let mut args = vec!["horizons", asset.to_str().unwrap(), "--distance", "-q"];
        args.extend_from_slice(extra);
        let o = terrabake(&args);
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        let a = terrabake_format::Asset::open(&asset).unwrap();
        let (angles, metres) = (
            a.layer("horizon", 0).unwrap(),
            a.layer("horizon_distance", 0).unwrap(),
        );
        assert_eq!(metres.bands(), angles.bands(), "{extra:?}");
        let mut v = vec![0f32; metres.width() as usize * metres.height() as usize];
        metres.read_rows_f32(1, 0, &mut v).unwrap();
        let measured = v.iter().filter(|d| d.is_finite()).count();
        assert!(
            measured > v.len() / 2 && v.iter().all(|d| d.is_nan() || *d > 0.0),
            "{extra:?}: {measured} of {} measured",
            v.len()
        );
    }
}

/// A 60 x 44 fractal baked in 16-post tiles (zstd heights, u8 horizons in
/// 8 directions, the sky): what the array exports' tests write out.
fn bake_exports_fixture(dir: &std::path::Path) -> std::path::PathBuf {
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let tif = dir.join("dem.tif");
    let o = terrabake(&["synth", "fractal", "--size", "60x44", "-o", &s(&tif), "-q"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let recipe = dir.join("r.toml");
    std::fs::write(
        &recipe,
        "[ingest]\ntile = 16\ncodec = \"zstd\"\n[[stage]]\nname = \"horizons\"\nsectors = 8\nencoding = \"u8\"\n[[stage]]\nname = \"sky\"\n",
    )
    .unwrap();
    let asset_dir = dir.join("dem.tbake");
    let o = terrabake(&[
        "bake",
        &s(&tif),
        "-o",
        &s(&asset_dir),
        "--recipe",
        &s(&recipe),
        "-q",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    asset_dir
}

/// A Zarr v3 array read from its `zarr.json` and chunk files as the spec
/// says (regular grid, default keys, bytes then zstd), CF-decoded
/// (`_FillValue` to NaN, then `scale_factor` and `add_offset`): its
/// metadata and values, row-major.
fn read_zarr_array(dir: &std::path::Path) -> (serde_json::Value, Vec<f64>) {
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("zarr.json")).unwrap()).unwrap();
    let shape: Vec<usize> = serde_json::from_value(meta["shape"].clone()).unwrap();
    let chunk: Vec<usize> =
        serde_json::from_value(meta["chunk_grid"]["configuration"]["chunk_shape"].clone()).unwrap();
    assert_eq!(meta["codecs"][1]["name"], "zstd");
    let attrs = &meta["attributes"];
    let (scale, offset) = (
        attrs["scale_factor"].as_f64().unwrap_or(1.0),
        attrs["add_offset"].as_f64().unwrap_or(0.0),
    );
    let fill = attrs["_FillValue"].as_f64();
    let decode = |bytes: &[u8]| -> Vec<f64> {
        let code: Vec<f64> = match meta["data_type"].as_str().unwrap() {
            "float32" => bytes
                .chunks_exact(4)
                .map(|b| f64::from(f32::from_le_bytes(b.try_into().unwrap())))
                .collect(),
            "float64" => bytes
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
                .collect(),
            "int64" => bytes
                .chunks_exact(8)
                .map(|b| i64::from_le_bytes(b.try_into().unwrap()) as f64)
                .collect(),
            "uint16" => bytes
                .chunks_exact(2)
                .map(|b| f64::from(u16::from_le_bytes(b.try_into().unwrap())))
                .collect(),
            "uint8" => bytes.iter().map(|&b| f64::from(b)).collect(),
            other => panic!("data type {other}"),
        };
        code.into_iter()
            .map(|c| {
                if Some(c) == fill {
                    f64::NAN
                } else {
                    offset + scale * c
                }
            })
            .collect()
    };
    let n: usize = shape.iter().product();
    let mut out = vec![f64::NAN; n];
    if shape.is_empty() {
        let v = decode(&zstd::decode_all(&std::fs::read(dir.join("c")).unwrap()[..]).unwrap());
        return (meta, v);
    }
    let grid: Vec<usize> = shape
        .iter()
        .zip(&chunk)
        .map(|(s, c)| s.div_ceil(*c))
        .collect();
    let chunks: usize = grid.iter().product();
    for k in 0..chunks {
        let mut index = vec![0; grid.len()];
        let mut rest = k;
        for d in (0..grid.len()).rev() {
            index[d] = rest % grid[d];
            rest /= grid[d];
        }
        let key: Vec<String> = index.iter().map(|i| i.to_string()).collect();
        let stored = std::fs::read(dir.join("c").join(key.join("/"))).unwrap();
        let values = decode(&zstd::decode_all(&stored[..]).unwrap());
        assert_eq!(
            values.len(),
            chunk.iter().product::<usize>(),
            "a whole chunk, padded"
        );
        for (j, v) in values.into_iter().enumerate() {
            let mut at = vec![0; chunk.len()];
            let mut rest = j;
            for d in (0..chunk.len()).rev() {
                at[d] = index[d] * chunk[d] + rest % chunk[d];
                rest /= chunk[d];
            }
            if at.iter().zip(&shape).all(|(a, s)| a < s) {
                let flat = at.iter().zip(&shape).fold(0, |acc, (a, s)| acc * s + a);
                out[flat] = v;
            }
        }
    }
    (meta, out)
}

/// `export --layer all -o X.zarr`: every layer on the post grid as a Zarr
/// v3 array equal to what the asset decodes (zstd heights copied as
/// stored, raw u8 horizon codes compressed, packed with CF's
/// scale_factor and add_offset, nodata code 0), the azimuth coordinate the
/// recorded band azimuths, x and y the post centres; a store exported
/// again is replaced whole; a directory that is not a Zarr store, and a
/// link, are refused with nothing written.
#[test]
fn zarr_export_reads_back_as_the_asset_decodes() {
    let dir = tempfile::tempdir().unwrap();
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let asset_dir = bake_exports_fixture(dir.path());
    let out = dir.path().join("dem.zarr");
    let export = || terrabake(&["export", &s(&asset_dir), "--layer", "all", "-o", &s(&out)]);
    let o = export();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("copied as stored"), "{}", stderr(&o));

    let asset = terrabake_format::Asset::open(&asset_dir).unwrap();
    let group: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("zarr.json")).unwrap()).unwrap();
    assert_eq!(group["node_type"], "group");
    let consolidated = group["consolidated_metadata"]["metadata"]
        .as_object()
        .unwrap();
    let mut checked = Vec::new();
    for layer in asset
        .layers()
        .iter()
        .filter(|l| l.entry().level == 0 && l.width() == 60)
    {
        let name = &layer.entry().name;
        let (meta, got) = read_zarr_array(&out.join(name));
        assert_eq!(&consolidated[name.as_str()], &meta, "{name}");
        let (w, h) = (layer.width(), layer.height());
        let mut want = vec![0f32; (w * h) as usize];
        for b in 0..layer.bands() {
            layer.read_rows_f32(b, 0, &mut want).unwrap();
            let plane = &got[(b * w * h) as usize..((b + 1) * w * h) as usize];
            for (i, (g, w)) in plane.iter().zip(&want).enumerate() {
                assert!(
                    (g.is_nan() && w.is_nan()) || *g as f32 == *w,
                    "{name} band {b} element {i}: {g} from Zarr, {w} from the asset"
                );
            }
        }
        checked.push(name.clone());
        if name == "horizon" {
            assert_eq!(meta["data_type"], "uint8", "codes, not widened");
            assert_eq!(
                meta["dimension_names"],
                serde_json::json!(["azimuth", "y", "x"])
            );
            assert_eq!(
                meta["chunk_grid"]["configuration"]["chunk_shape"],
                serde_json::json!([1, 16, 16])
            );
            let (_, azimuths) = read_zarr_array(&out.join("azimuth"));
            assert_eq!(azimuths, layer.entry().band_azimuths);
        }
    }
    assert!(
        checked.len() >= 5 && checked.contains(&"height".to_string()),
        "{checked:?}"
    );
    let t = asset
        .manifest()
        .georef
        .as_ref()
        .unwrap()
        .corner_geotransform();
    let (_, xs) = read_zarr_array(&out.join("x"));
    let (_, ys) = read_zarr_array(&out.join("y"));
    assert_eq!((xs.len(), ys.len()), (60, 44));
    assert!(
        (xs[1] - (t[0] + 1.5 * t[1])).abs() < 1e-9 && (ys[0] - (t[3] + 0.5 * t[5])).abs() < 1e-9
    );

    // Exported again: replaced whole, nothing left beside it.
    std::fs::write(out.join("stray"), b"from before").unwrap();
    let o = export();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!out.join("stray").exists());
    let beside: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(beside.is_empty(), "{beside:?}");

    // A user's directory, and a link, are not replaced.
    let theirs = dir.path().join("theirs.zarr");
    std::fs::create_dir(&theirs).unwrap();
    std::fs::write(theirs.join("notes.txt"), b"mine").unwrap();
    let link = dir.path().join("link.zarr");
    std::os::unix::fs::symlink(&out, &link).unwrap();
    for target in [&theirs, &link] {
        let o = terrabake(&["export", &s(&asset_dir), "--layer", "svf", "-o", &s(target)]);
        assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
        assert!(stderr(&o).contains("is not a Zarr store"), "{}", stderr(&o));
    }
    assert_eq!(std::fs::read(theirs.join("notes.txt")).unwrap(), b"mine");
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    // Several layers go to a store only.
    let o = terrabake(&[
        "export",
        &s(&asset_dir),
        "--layer",
        "svf",
        "--layer",
        "height",
        "-o",
        &s(&dir.path().join("x.tif")),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("only a .zarr store"), "{}", stderr(&o));
}

/// `export --layer all -o X.nc` writes a whole HDF5 file: the superblock's
/// checksum holds, it names the file's length and a checksummed root
/// group; `ncdump` (netCDF-C, where installed) lists the dimensions and
/// gives the horizons' u8 codes equal to the asset's. A link at the output
/// is replaced, never written through. The Python tests read the file with
/// netCDF4, h5netcdf and GDAL (python/tests/test_netcdf_export.py). The
/// checksum is HDF5's lookup3, checked against Jenkins' own vectors in its
/// unit test.
#[test]
fn netcdf_export_is_a_whole_hdf5_file_that_netcdf_reads() {
    use terrabake::export::hdf5::checksum;
    let dir = tempfile::tempdir().unwrap();
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let asset_dir = bake_exports_fixture(dir.path());
    // The output is a link to someone's file: replaced, the file untouched.
    let victim = dir.path().join("victim.txt");
    std::fs::write(&victim, b"mine").unwrap();
    let out = dir.path().join("dem.nc");
    std::os::unix::fs::symlink(&victim, &out).unwrap();
    let o = terrabake(&["export", &s(&asset_dir), "--layer", "all", "-o", &s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(&victim).unwrap(), b"mine");
    assert!(std::fs::symlink_metadata(&out).unwrap().is_file());

    let bytes = std::fs::read(&out).unwrap();
    assert_eq!(
        &bytes[..9],
        b"\x89HDF\r\n\x1a\n\x02",
        "superblock version 2"
    );
    let u64_at = |i: usize| u64::from_le_bytes(bytes[i..i + 8].try_into().unwrap());
    assert_eq!(
        checksum(&bytes[..44]),
        u32::from_le_bytes(bytes[44..48].try_into().unwrap())
    );
    assert_eq!(u64_at(28), bytes.len() as u64, "end of file address");
    let root = u64_at(36) as usize;
    assert_eq!(&bytes[root..root + 5], b"OHDR\x02");
    let width = 1 << (bytes[root + 5] & 3);
    let body = (0..width).fold(0usize, |n, i| {
        n | (bytes[root + 10 + i] as usize) << (8 * i)
    });
    let end = root + 10 + width + body;
    assert_eq!(
        checksum(&bytes[root..end]),
        u32::from_le_bytes(bytes[end..end + 4].try_into().unwrap())
    );

    let Ok(dump) = std::process::Command::new("ncdump")
        .args(["-v", "horizon"])
        .arg(&out)
        .output()
    else {
        eprintln!(
            "ncdump is not installed (netcdf-bin): the NetCDF read-back is left to python/tests"
        );
        return;
    };
    let text = String::from_utf8_lossy(&dump.stdout);
    assert!(
        dump.status.success(),
        "{}",
        String::from_utf8_lossy(&dump.stderr)
    );
    for line in [
        "y = 44 ;",
        "x = 60 ;",
        "azimuth = 8 ;",
        "ubyte horizon(azimuth, y, x) ;",
    ] {
        assert!(text.contains(line), "{line} missing from\n{text}");
    }
    let data = &text[text.find("horizon =").unwrap() + 9..];
    let codes: Vec<u8> = data[..data.find(';').unwrap()]
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|t| !t.is_empty())
        .map(|t| t.parse().unwrap())
        .collect();
    let asset = terrabake_format::Asset::open(&asset_dir).unwrap();
    let layer = asset.layer("horizon", 0).unwrap();
    let mut want = Vec::new();
    for b in 0..8 {
        for y in 0..44 {
            for x in 0..60 {
                want.push(layer.get::<u8>(b, x, y).unwrap());
            }
        }
    }
    assert_eq!(codes, want);
}
