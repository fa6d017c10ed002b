//! Viewsheds against exact references: the observer viewshed's block walk
//! against every crossing of every sight line, the total viewshed's hull
//! tree against the naive walk, and both against geometry worked by hand.

mod common;

use proptest::prelude::*;
use terrabake::algorithms::viewshed::observer::{
    line_of_sight, observer_viewshed, Observer, OUTSIDE,
};
use terrabake::algorithms::viewshed::total::{
    total_viewshed, total_viewshed_at, Method, TotalOptions,
};
use terrabake::io::synth::{fill_rows, SynthKind};
use terrabake::terrain::Terrain;

fn synth(kind: SynthKind, w: usize, h: usize, seed: u64) -> Vec<f32> {
    let mut z = vec![0f32; w * h];
    fill_rows(kind, 0, &mut z, w as u32, h as u32, seed);
    z
}

fn assert_equals_reference(terrain: &Terrain, obs: &Observer) {
    let got = observer_viewshed(terrain, obs);
    for row in 0..terrain.height {
        for col in 0..terrain.width {
            let want = line_of_sight(terrain, obs, (col, row)).map_or(OUTSIDE, u8::from);
            assert_eq!(
                got.visible[row * terrain.width + col],
                want,
                "post ({col}, {row}) from {obs:?}"
            );
        }
    }
}

#[test]
fn a_wall_hides_the_plain_behind_it_to_where_theory_says() {
    // Plain at 0, a wall of posts 5 m high at column 10, eye 10 m up at
    // column 0: a target at column x behind the wall is hidden while the
    // sight line passes below the wall's top, 10 (1 - 10 / x) < 5: x < 20.
    let (w, h) = (40, 3);
    let mut z = vec![0f32; w * h];
    for row in 0..h {
        z[row * w + 10] = 5.0;
    }
    let t = Terrain::new(&z, w, h, 1.0, 1.0);
    let obs = Observer {
        col: 0,
        row: 1,
        height: 10.0,
        target_height: 0.0,
        max_distance: None,
    };
    let v = observer_viewshed(&t, &obs);
    let row: Vec<u8> = v.visible[w..2 * w].to_vec();
    for (x, &seen) in row.iter().enumerate() {
        assert_eq!(seen, u8::from(x <= 10 || x >= 20), "column {x}");
    }
    // The elevation angle of the wall's top: atan(-5 / 10).
    assert!((v.angle[w + 10] - (-5f32 / 10.0).atan().to_degrees()).abs() < 1e-5);
    assert_eq!(v.angle[w], -90.0);
}

#[test]
fn curvature_hides_what_lies_below_the_horizon() {
    // A flat earth sees a distant mast; a curved one hides its foot.
    // Two rows: a single row has no cells, so no surface to block.
    let (w, h) = (200, 2);
    let z = vec![0f32; w * h];
    let flat = Terrain::new(&z, w, h, 100.0, 100.0);
    let round = flat.with_curvature(terrabake::terrain::curvature_coefficient(0.13));
    let obs = Observer {
        col: 0,
        row: 0,
        height: 2.0,
        target_height: 0.0,
        max_distance: Some(15_000.0),
    };
    let (a, b) = (
        observer_viewshed(&flat, &obs),
        observer_viewshed(&round, &obs),
    );
    assert!(a.visible[1..=150].iter().all(|&v| v == 1));
    assert!(a.visible[151..w].iter().all(|&v| v == OUTSIDE));
    // The horizon of a 2 m eye is about 5.4 km away with refraction 0.13;
    // the ground beyond it is hidden.
    assert_eq!(b.visible[40], 1);
    assert!(b.visible[70..=150].iter().all(|&v| v == 0));
}

#[test]
fn block_walk_equals_every_crossing_on_synthetic_terrains() {
    let (w, h) = (150, 130);
    for (kind, seed) in [
        (SynthKind::Fractal, 3),
        (SynthKind::Blocks, 5),
        (SynthKind::Holes, 7),
        (SynthKind::Quantised, 9),
    ] {
        let z = synth(kind, w, h, seed);
        let t = Terrain::new(&z, w, h, 30.0, 25.0)
            .with_curvature(terrabake::terrain::curvature_coefficient(0.13));
        for (col, row, height) in [(75, 60, 1.7), (3, 120, 30.0), (149, 0, 0.0)] {
            if z[row * w + col].is_nan() {
                continue;
            }
            let obs = Observer {
                col,
                row,
                height,
                target_height: 2.0,
                max_distance: Some(3000.0),
            };
            assert_equals_reference(&t, &obs);
        }
    }
}

fn relative_gap(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .filter(|(x, _)| !x.is_nan())
        .map(|(x, y)| (x - y).abs() / (1.0 + x.abs()))
        .fold(0.0, f64::max)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Random small terrains with ties (integer heights) and holes.
    #[test]
    fn observer_viewshed_equals_line_of_sight(
        (w, h, z) in (2usize..40, 2usize..40).prop_flat_map(|(w, h)| {
            (Just(w), Just(h), prop::collection::vec(
                prop_oneof![8 => (0i8..6).prop_map(f32::from), 1 => Just(f32::NAN)], w * h))
        }),
        at in (0.0f64..1.0, 0.0f64..1.0),
        (height, target_height) in (0.0f64..4.0, 0.0f64..2.0),
        curved in any::<bool>(),
    ) {
        let (col, row) = ((at.0 * w as f64) as usize, (at.1 * h as f64) as usize);
        prop_assume!(!z[row * w + col].is_nan());
        let t = Terrain::new(&z, w, h, 1.0, 1.5).with_curvature(if curved { 1e-3 } else { 0.0 });
        let obs = Observer { col, row, height, target_height, max_distance: None };
        assert_equals_reference(&t, &obs);
    }

    /// The hull tree's areas are the naive walk's, with raised eyes,
    /// curvature, holes and a maximum distance.
    #[test]
    fn total_viewshed_hull_tree_equals_naive(
        (w, h, z) in (2usize..24, 2usize..24).prop_flat_map(|(w, h)| {
            (Just(w), Just(h), prop::collection::vec(
                prop_oneof![12 => -20f32..20.0, 1 => Just(f32::NAN)], w * h))
        }),
        height in prop_oneof![Just(0.0), 0.0f64..5.0],
        max_distance in prop_oneof![Just(None), (2.0f64..30.0).prop_map(Some)],
        directions in 3usize..24,
        safe_zone in any::<bool>(),
        curved in any::<bool>(),
    ) {
        let t = Terrain::new(&z, w, h, 1.0, 1.3).with_curvature(if curved { 1e-3 } else { 0.0 });
        let opts = TotalOptions { height, max_distance, directions, method: Method::Naive };
        let (naive, ns) = total_viewshed(&t, &opts, &|| ());
        let (tree, ts) = total_viewshed(&t, &TotalOptions { method: Method::HullTree { safe_zone }, ..opts }, &|| ());
        prop_assert!(relative_gap(&naive, &tree) < 1e-9, "{:?} vs {:?}", naive, tree);
        if max_distance.is_none() {
            prop_assert_eq!(ns.visible_vertices, ts.visible_vertices);
        }
    }

    /// The areas at chosen posts alone (each post's lines walked from two
    /// steps past its reach) are the whole sweep's there.
    #[test]
    fn total_viewshed_at_posts_equals_the_sweep(
        (w, h, z) in (2usize..28, 2usize..28).prop_flat_map(|(w, h)| {
            (Just(w), Just(h), prop::collection::vec(
                prop_oneof![12 => -20f32..20.0, 1 => Just(f32::NAN)], w * h))
        }),
        height in prop_oneof![Just(0.0), 0.0f64..5.0],
        max_distance in prop_oneof![Just(None), (1.0f64..30.0).prop_map(Some)],
        directions in 3usize..24,
        curved in any::<bool>(),
    ) {
        let t = Terrain::new(&z, w, h, 1.0, 1.3).with_curvature(if curved { 1e-3 } else { 0.0 });
        let opts = TotalOptions { height, max_distance, directions, method: Method::Naive };
        let (all, _) = total_viewshed(&t, &opts, &|| ());
        let posts: Vec<(usize, usize)> = (0..w * h).step_by(3).map(|i| (i % w, i / w)).collect();
        let at = total_viewshed_at(&t, &opts, &posts);
        let want: Vec<f64> = posts.iter().map(|&(c, r)| all[r * w + c]).collect();
        prop_assert!(relative_gap(&want, &at) < 1e-9, "{:?} vs {:?}", want, at);
        prop_assert!(want.iter().zip(&at).all(|(a, b)| a.is_nan() == b.is_nan()));
    }
}

#[test]
fn total_viewshed_converges_on_the_observer_viewsheds() {
    // On smooth terrain the area seen from a post, with many directions,
    // approaches the count of posts its observer viewshed sees times a
    // post's area. (On rough terrain counting posts overstates the area:
    // a post seen on a crest counts a whole cell whose slopes are hidden,
    // Timonen's sampling error; docs/VISIBILITY.md charts both.)
    let (w, h) = (64, 64);
    let z = synth(SynthKind::Sine, w, h, 11);
    let t = Terrain::new(&z, w, h, 10.0, 10.0);
    let opts = |directions| TotalOptions {
        height: 1.7,
        max_distance: Some(250.0),
        directions,
        method: Method::HullTree { safe_zone: true },
    };
    let error = |directions| {
        let (area, _) = total_viewshed(&t, &opts(directions), &|| ());
        let mut sum = 0.0;
        let mut n = 0.0;
        for (col, row) in [(32, 32), (20, 40), (45, 25), (30, 10)] {
            let obs = Observer {
                col,
                row,
                height: 1.7,
                target_height: 0.0,
                max_distance: Some(250.0),
            };
            let v = observer_viewshed(&t, &obs);
            let seen = v.visible.iter().filter(|&&s| s == 1).count() as f64 * 100.0;
            sum += (area[row * w + col] - seen).abs() / seen;
            n += 1.0;
        }
        sum / n
    };
    let fine = error(128);
    assert!(
        fine < 0.03,
        "mean relative error {fine} with 128 directions"
    );
}

mod cli {
    use super::*;
    use crate::common::{self, stderr, stdout, terrabake};
    use terrabake_format::layers::{TOTAL_VIEWSHED, VIEWSHED, VIEWSHED_ANGLE};
    use terrabake_format::Asset;

    /// A synthetic GeoTIFF `dir/t.tif`.
    fn synth_tif(dir: &std::path::Path, kind: SynthKind, (w, h): (u32, u32)) -> std::path::PathBuf {
        let tif = dir.join("t.tif");
        terrabake::io::synth::write_geotiff(
            &tif,
            kind,
            w,
            h,
            4,
            terrabake::plumbing::progress::Progress::hidden(),
        )
        .unwrap();
        tif
    }

    /// A 96 x 80 fractal asset (a local metric grid).
    fn asset(dir: &std::path::Path) -> std::path::PathBuf {
        let tif = synth_tif(dir, SynthKind::Fractal, (96, 80));
        let out = dir.join("t.tbake");
        let o = terrabake(&[
            "ingest",
            tif.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        out
    }

    #[test]
    fn the_command_writes_the_viewshed_that_the_algorithm_computes() {
        let dir = tempfile::tempdir().unwrap();
        let a = asset(dir.path());
        let tif = dir.path().join("vs.tif");
        let o = terrabake(&[
            "viewshed",
            a.to_str().unwrap(),
            "--observer",
            "40,30",
            "--crs",
            "grid",
            "--observer-height",
            "5",
            "--max-distance",
            "400",
            "-o",
            tif.to_str().unwrap(),
            "--json",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let summary: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
        assert_eq!(summary["observer_post"], serde_json::json!([40, 30]));
        // The same count from the algorithm on the asset's heights.
        let opened = Asset::open(&a).unwrap();
        let z = common::heights(&opened);
        let cs = &opened.manifest().cell_size;
        let t = Terrain::new(&z, 96, 80, cs.dx, cs.dy);
        let v = observer_viewshed(
            &t,
            &Observer {
                col: 40,
                row: 30,
                height: 5.0,
                target_height: 0.0,
                max_distance: Some(400.0),
            },
        );
        let seen = v.visible.iter().filter(|&&s| s == 1).count();
        assert_eq!(summary["posts_visible"], serde_json::json!(seen));
        // Band 1 of the GeoTIFF is the visibility, NaN outside the distance
        // (the image is one tile per band: band 1 is chunk 0).
        let mut dec = tiff::decoder::Decoder::new(std::fs::File::open(&tif).unwrap()).unwrap();
        let (cw, _) = dec.chunk_data_dimensions(0);
        let tiff::decoder::DecodingResult::F32(px) = dec.read_chunk(0).unwrap() else {
            panic!("float32 bands")
        };
        for (i, &want) in v.visible.iter().enumerate() {
            let got = px[(i / 96) * cw as usize + i % 96];
            match want {
                OUTSIDE => assert!(got.is_nan()),
                w => assert_eq!(got, f32::from(w)),
            }
        }
    }

    #[test]
    fn bad_observers_and_heights_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let a = asset(dir.path());
        let out = dir.path().join("vs.tif");
        let run = |extra: &[&str]| {
            let mut args = vec!["viewshed", a.to_str().unwrap(), "-o", out.to_str().unwrap()];
            args.extend_from_slice(extra);
            terrabake(&args)
        };
        for (extra, says, code) in [
            (
                &["--observer", "500,3", "--crs", "grid"][..],
                "outside the 96 x 80 DEM",
                1,
            ),
            (
                &[
                    "--observer",
                    "5,5",
                    "--crs",
                    "grid",
                    "--observer-height",
                    "-2",
                ][..],
                "--observer-height -2",
                1,
            ),
            (
                &["--observer", "5,5", "--crs", "lonlat"][..],
                "neither on a geographic grid",
                1,
            ),
            (
                &["--observer", "5,5", "--crs", "grid", "--max-distance", "0"][..],
                "positive number",
                2,
            ),
            (&["--observer", "5"][..], "expected X,Y", 2),
        ] {
            let o = run(extra);
            assert_eq!(o.status.code(), Some(code), "{extra:?}: {}", stderr(&o));
            assert!(stderr(&o).contains(says), "{extra:?}: {}", stderr(&o));
            assert!(!stderr(&o).contains("panicked"));
        }
        assert!(!out.exists(), "nothing written on a refusal");
        // An observer on a nodata post.
        let holes = dir.path().join("holes");
        std::fs::create_dir(&holes).unwrap();
        let tif = synth_tif(&holes, SynthKind::Holes, (64, 64));
        let a = holes.join("h.tbake");
        assert!(terrabake(&[
            "ingest",
            tif.to_str().unwrap(),
            "-o",
            a.to_str().unwrap(),
            "-q"
        ])
        .status
        .success());
        let z = common::heights(&Asset::open(&a).unwrap());
        let hole = z.iter().position(|v| v.is_nan()).expect("a hole");
        let at = format!("{},{}", hole % 64, hole / 64);
        let o = terrabake(&[
            "viewshed",
            a.to_str().unwrap(),
            "--observer",
            &at,
            "--crs",
            "grid",
            "-o",
            out.to_str().unwrap(),
        ]);
        assert_eq!(o.status.code(), Some(1));
        assert!(
            stderr(&o).contains("which has no height (nodata)"),
            "{}",
            stderr(&o)
        );
    }

    #[test]
    fn a_recipe_bakes_observers_and_the_total_viewshed() {
        let dir = tempfile::tempdir().unwrap();
        let tif = synth_tif(dir.path(), SynthKind::Sine, (64, 48));
        let recipe = dir.path().join("r.toml");
        std::fs::write(
            &recipe,
            "[[stage]]\nname = \"viewshed\"\nobservers = [[10.0, 10.0], [50.0, 40.0]]\ncrs = \"grid\"\nobserver_height = 3.0\n\n\
             [[stage]]\nname = \"total_viewshed\"\ndirections = 16\nmax_distance = 300.0\n",
        )
        .unwrap();
        let out = dir.path().join("t.tbake");
        let o = terrabake(&[
            "bake",
            tif.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--recipe",
            recipe.to_str().unwrap(),
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let opened = Asset::open(&out).unwrap();
        assert_eq!(opened.layer(VIEWSHED, 0).unwrap().entry().bands, 2);
        assert_eq!(opened.layer(VIEWSHED_ANGLE, 0).unwrap().entry().bands, 2);
        // The stored total viewshed is the algorithm's (f32 of the f64 sums).
        let z = common::heights(&opened);
        let cs = &opened.manifest().cell_size;
        let curvature = terrabake::terrain::held::curvature_for(opened.manifest(), None, 0.13);
        let t = Terrain::new(&z, 64, 48, cs.dx, cs.dy).with_curvature(curvature);
        let (want, _) = total_viewshed(
            &t,
            &TotalOptions {
                height: 1.7,
                max_distance: Some(300.0),
                directions: 16,
                method: Method::Naive,
            },
            &|| (),
        );
        let layer = opened.layer(TOTAL_VIEWSHED, 0).unwrap();
        let mut got = vec![0f32; 64 * 48];
        layer.read_window(0, 0, 0, 64, 48, &mut got).unwrap();
        for (g, w) in got.iter().zip(&want) {
            assert!(
                (f64::from(*g) - w).abs() <= 1e-6 * w.abs().max(1.0),
                "{g} vs {w}"
            );
        }
        // A recipe's unknown key is refused by name.
        std::fs::write(
            &recipe,
            "[[stage]]\nname = \"total_viewshed\"\ndirection = 16\n",
        )
        .unwrap();
        let o = terrabake(&[
            "bake",
            tif.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--recipe",
            recipe.to_str().unwrap(),
        ]);
        assert!(!o.status.success());
        assert!(stderr(&o).contains("direction"), "{}", stderr(&o));
    }
}
