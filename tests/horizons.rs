//! Horizons against their definitions, by brute force at every post: `line`
//! against the surface sampled at every crossing of the post's own line
//! (`horizon::brute::line_horizon`), `sector` against every post of the DEM
//! tested for membership of the closed wedge (`horizon::brute::
//! sector_horizon`), on every synthetic terrain and a crop of the real DEM,
//! for s in {4, 7, 16, 64, 256}; then the failure cases the papers name,
//! each measured.

mod common;

use terrabake::algorithms::horizon::brute;
use terrabake::algorithms::horizon::line::{self, GridDirection};
use terrabake::algorithms::horizon::sector::{sector_horizons, NarrowStencil, SectorFrame};
use terrabake::algorithms::horizon::{band_horizons, plan_bands, BandKind, BandOptions, Method};
use terrabake::algorithms::viewshed::hull_tree::{local_horizons_brute, HullTree};
use terrabake::io::synth::{self, SynthKind};
use terrabake::terrain::{curvature_coefficient, RowScale, Terrain};

const COUNTS: [usize; 5] = [4, 7, 16, 64, 256];

fn synth_grid(kind: SynthKind, w: usize, h: usize, seed: u64) -> Vec<f32> {
    let mut z = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            z.push(synth::height(
                kind, x as u32, y as u32, w as u32, h as u32, seed,
            ));
        }
    }
    z
}

/// Same angle, or both nodata. Without curvature the fast methods and the
/// references evaluate the same slope formula at the same point, so they
/// agree to the last bit of f32 but for rounding in the crossing heights.
fn same(a: f32, b: f32, tol: f32) -> bool {
    (a.is_nan() && b.is_nan()) || (a - b).abs() <= tol
}

fn check_line(name: &str, t: &Terrain, dir: &GridDirection, tol: f32) {
    let mut out = vec![0f32; t.z.len()];
    line::line_horizons(t, dir, &mut out);
    for row in 0..t.height {
        for col in 0..t.width {
            let got = out[row * t.width + col];
            let want = brute::line_horizon(t, (col, row), dir.step, None);
            assert!(
                same(got, want, tol),
                "{name}: line {:?} at ({col}, {row}): sweep {got}, brute force {want}",
                dir.step
            );
        }
    }
}

fn check_sector(name: &str, t: &Terrain, index: usize, count: usize, narrow: bool, tol: f32) {
    let mut out = vec![0f32; t.z.len()];
    sector_horizons(t, index, count, narrow, &mut out);
    let frame = SectorFrame::new(index, count, t.dx, t.dy);
    let stencil = narrow.then(|| NarrowStencil::new(&frame, count, t.dx, t.dy));
    for row in 0..t.height {
        for col in 0..t.width {
            let got = out[row * t.width + col];
            let want = brute::sector_horizon(t, (col, row), &frame, stencil.as_ref(), None);
            assert!(
                same(got, want, tol),
                "{name}: sector {index}/{count} (narrow {narrow}) at ({col}, {row}): tree {got}, brute force {want}"
            );
        }
    }
}

fn check_all(name: &str, t: &Terrain) {
    for count in COUNTS {
        for band in plan_bands(Method::Line, count, t.dx, t.dy, None) {
            let BandKind::Line(dir) = &band.kind else {
                unreachable!()
            };
            check_line(name, t, dir, 1e-4);
        }
        for index in 0..count {
            check_sector(name, t, index, count, count == 256, 1e-4);
        }
    }
}

#[test]
fn line_and_sector_equal_brute_force_on_every_synthetic_terrain() {
    for (i, kind) in SynthKind::ALL.into_iter().enumerate() {
        // Non-square cells on odd kinds: directions off the grid diagonals.
        let (w, h) = (23, 19);
        let z = synth_grid(kind, w, h, 5 + i as u64);
        let dy = if i % 2 == 1 { 20.0 } else { 30.0 };
        let t = Terrain::new(&z, w, h, 30.0, dy);
        check_all(&format!("{kind:?}"), &t);
    }
}

/// Lines through posts that only a corner ties to the surface: between two
/// holes, a sight line grazes a post of a cell it never enters. Random
/// terrains a third nodata, every grid step up to 5 posts: the sweep meets
/// those posts as the brute force does (it missed them once, found by
/// `terrabake check` on the holes terrain: up to 59 degrees too low).
#[test]
fn line_horizons_meet_posts_between_holes() {
    let mut seed = 0x5eed_u64;
    let mut next = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 33) as u32
    };
    for trial in 0..6 {
        let (w, h) = (14, 11);
        let z: Vec<f32> = (0..w * h)
            .map(|_| {
                if next() % 3 == 0 {
                    f32::NAN
                } else {
                    (next() % 50) as f32
                }
            })
            .collect();
        let t = Terrain::new(&z, w, h, 10.0, 10.0);
        for a in -5i64..=5 {
            for b in -5i64..=5 {
                let (mut x, mut y) = (a.abs(), b.abs());
                while y != 0 {
                    (x, y) = (y, x % y);
                }
                if x != 1 {
                    continue; // (0, 0) and steps that are multiples of shorter ones
                }
                let dir = GridDirection {
                    step: (a, b),
                    azimuth: (a as f64).atan2(-(b as f64)).to_degrees().rem_euclid(360.0),
                    nominal: 0.0,
                };
                check_line(&format!("holes {trial}"), &t, &dir, 1e-4);
            }
        }
    }
}

#[test]
fn line_and_sector_equal_brute_force_on_the_real_dem_with_curvature() {
    let (z, dx, dy) = common::srtm_crop((600, 400), (24, 20));
    let t = Terrain::new(&z, 24, 20, dx, dy);
    check_all("SRTM crop", &t);
    // Curvature and refraction: the hull of z - c t^2 against the drop
    // applied post by post (rounding differs, hence the tolerance).
    let curved = t.with_curvature(curvature_coefficient(0.13));
    for count in [7, 16] {
        for band in plan_bands(Method::Line, count, dx, dy, None) {
            let BandKind::Line(dir) = &band.kind else {
                unreachable!()
            };
            check_line("SRTM crop, curved", &curved, dir, 1e-3);
        }
        for index in 0..count {
            check_sector("SRTM crop, curved", &curved, index, count, true, 1e-3);
        }
    }
}

/// The half-row scales of a geographic grid whose `h` rows run from
/// latitude `lat0` down by `dlat` degrees a row (`geo::row_scale`, the
/// stage's own).
fn geographic_scale(h: usize, lat0: f64, dlat: f64) -> Vec<f64> {
    use terrabake::terrain::geo::{georef_from_keys, row_scale, GT_MODEL_TYPE};
    let georef = georef_from_keys(
        vec![1, 1, 0, 1, GT_MODEL_TYPE, 0, 1, 2],
        vec![],
        String::new(),
        [0.0, 1.0 / 1200.0, 0.0, lat0, 0.0, -dlat],
    );
    row_scale(Some(&georef), h as u32)
}

#[test]
fn line_and_sector_equal_brute_force_on_geographic_grids() {
    // Rows from 70 N to 41.5 N: the east-west spacing more than doubles
    // from top to bottom (far beyond any real tile, to make every error in
    // the per-row geometry show).
    let (w, h) = (23, 20);
    let scale = geographic_scale(h, 70.0, 1.5);
    assert!(scale[2 * (h - 1)] / scale[0] > 2.0);
    for (i, kind) in [SynthKind::Fractal, SynthKind::Noise, SynthKind::Holes]
        .into_iter()
        .enumerate()
    {
        let z = synth_grid(kind, w, h, 11 + i as u64);
        let t = Terrain::new(&z, w, h, 30.0, 25.0).with_row_scale(RowScale::new(&scale));
        check_all(&format!("{kind:?}, geographic"), &t);
        let curved = t.with_curvature(curvature_coefficient(0.13));
        for band in plan_bands(Method::Line, 16, t.dx, t.dy, None) {
            let BandKind::Line(dir) = &band.kind else {
                unreachable!()
            };
            check_line("geographic, curved", &curved, dir, 1e-3);
        }
    }
}

#[test]
fn geographic_rows_measure_east_west_distance_at_their_own_latitude() {
    // A wall 50 m high along the east edge: from a post k columns west of it,
    // looking east, the horizon is atan(50 / (k dx(row))), where dx(row) is
    // the spacing at the row's latitude, not the centre row's.
    let (w, h) = (12, 41);
    let scale = geographic_scale(h, 60.0, 0.5);
    // Rows from 60 N to 40 N.
    let mut z = vec![0f32; w * h];
    for row in 0..h {
        z[row * w + w - 1] = 50.0;
    }
    let t = Terrain::new(&z, w, h, 30.0, 30.0).with_row_scale(RowScale::new(&scale));
    // 60 N to 40 N: a degree of longitude is 0.65 times as long at the top.
    assert!(t.dx_at(0) < 0.7 * t.dx_at(h - 1));
    let east = plan_bands(Method::Line, 4, 30.0, 30.0, None).remove(1);
    let (out, _) = band_horizons(&t, &east, BandOptions::default());
    for row in [0, h / 2, h - 1] {
        for k in [1, 6] {
            let want = (50.0 / (k as f64 * t.dx_at(row))).atan().to_degrees();
            let got = f64::from(out[row * w + w - 1 - k]);
            assert!(
                (got - want).abs() < 1e-4,
                "row {row}, {k} west: {got} vs {want}"
            );
        }
    }
}

#[test]
fn a_flat_dem_has_every_horizon_at_zero() {
    let z = vec![100f32; 30 * 20];
    let t = Terrain::new(&z, 30, 20, 30.0, 30.0);
    for method in [Method::Line, Method::Sector, Method::Sampled] {
        for band in plan_bands(method, 16, 30.0, 30.0, None) {
            let (out, _) = band_horizons(
                &t,
                &band,
                BandOptions {
                    max_distance: None,
                    narrow_check: true,
                },
            );
            for (i, &a) in out.iter().enumerate() {
                // Posts on the edge facing out see nothing: -90.
                assert!(
                    a == 0.0 || a == -90.0,
                    "{method:?} {} post {i}: {a}",
                    band.azimuth
                );
            }
            assert!(out.iter().filter(|&&a| a == 0.0).count() > out.len() / 2);
        }
    }
    // With curvature the flat earth drops away: every horizon below zero.
    let curved = t.with_curvature(curvature_coefficient(0.13));
    let band = &plan_bands(Method::Line, 4, 30.0, 30.0, None)[1];
    let (out, _) = band_horizons(
        &curved,
        band,
        BandOptions {
            max_distance: None,
            narrow_check: true,
        },
    );
    assert!(out.iter().all(|&a| a < 0.0));
}

#[test]
fn points_exactly_on_sector_boundaries_belong_to_both_sectors() {
    // s = 4 puts the boundaries on the grid diagonals (sec. IV-D).
    let (w, h) = (9, 9);
    let mut z = vec![0f32; w * h];
    z[2 * w + 6] = 100.0; // post (6, 2)
    let t = Terrain::new(&z, w, h, 10.0, 10.0);
    let sectors: Vec<Vec<f32>> = (0..4)
        .map(|i| {
            let mut out = vec![0f32; w * h];
            sector_horizons(&t, i, 4, false, &mut out);
            out
        })
        .collect();
    let sees = |post: usize, sector: usize| sectors[sector][post] > 45.0;
    // From (4, 4) the spike is 2 east, 2 north: on the ray between N and E,
    // in both; the elevation is taken in each centre plane (20 m along).
    let ne = 4 * w + 4;
    let expected = (100f64 / 20.0).atan().to_degrees() as f32;
    assert_eq!(sectors[0][ne], expected);
    assert_eq!(sectors[1][ne], expected);
    assert!(!sees(ne, 2) && !sees(ne, 3));
    // From (8, 0) it is 2 west, 2 south: in S and W, and not in N or E,
    // although it lies on the line of their shared boundary, behind the apex.
    let sw = 8;
    assert!(sees(sw, 2) && sees(sw, 3));
    assert!(!sees(sw, 0) && !sees(sw, 1));
}

#[test]
fn the_spike_centre_line_sampling_misses_and_sectors_darken() {
    // Stewart's Fig. 8: flat ground, one tall spike. Sampling along the
    // sector centres misses it from most posts around; the sector method
    // sees it from every post whose wedge holds it, over the whole sector.
    let (w, h) = (61, 61);
    let mut z = vec![0f32; w * h];
    z[10 * w + 10] = 500.0;
    let t = Terrain::new(&z, w, h, 10.0, 10.0);
    let opts = BandOptions {
        max_distance: None,
        narrow_check: true,
    };
    let count = 16;
    let mut shadowed = [0usize; 3];
    for (m, method) in [Method::Sampled, Method::Line, Method::Sector]
        .into_iter()
        .enumerate()
    {
        for band in plan_bands(method, count, 10.0, 10.0, None) {
            let (out, _) = band_horizons(&t, &band, opts);
            shadowed[m] += out.iter().filter(|&&a| a > 5.0).count();
        }
    }
    let [sampled, line, sector] = shadowed;
    // Every post sees the spike in exactly one or two sectors (boundaries).
    assert!(sector >= w * h - 1, "sector: {sector}");
    assert!(sampled < sector / 4, "sampled {sampled} vs sector {sector}");
    assert!(line < sector / 4, "line {line} vs sector {sector}");
    eprintln!(
        "spike, posts x bands above 5 degrees: sampled {sampled}, line {line}, sector {sector}"
    );
}

#[test]
fn narrow_sectors_need_stewarts_check() {
    // s = 256, sector 5 (centre 7.03 degrees, 6.33..7.73): the first post
    // inside the wedge from (4, 20) is (5, 12), 8 rows north. A tall post 3
    // rows due north is outside the wedge, but its cell is crossed by it:
    // Stewart's IV-E check (Fig. 6) counts it; the bare wedge does not.
    let (w, h) = (12, 24);
    let mut z = vec![0f32; w * h];
    z[17 * w + 4] = 50.0;
    let t = Terrain::new(&z, w, h, 10.0, 10.0);
    let frame = SectorFrame::new(5, 256, 10.0, 10.0);
    let stencil = NarrowStencil::new(&frame, 256, 10.0, 10.0);
    assert!(stencil.offsets.contains(&(0, -3)));
    let receiver = (4, 20);
    let with = brute::sector_horizon(&t, receiver, &frame, Some(&stencil), None);
    let without = brute::sector_horizon(&t, receiver, &frame, None, None);
    assert!(with > 50.0, "with the check: {with}");
    assert_eq!(without, 0.0);
    let mut out = vec![0f32; w * h];
    sector_horizons(&t, 5, 256, true, &mut out);
    assert_eq!(out[receiver.1 * w + receiver.0], with);
    sector_horizons(&t, 5, 256, false, &mut out);
    assert_eq!(out[receiver.1 * w + receiver.0], without);
}

#[test]
fn the_bowl_is_timonens_worst_case_and_stays_linear_per_vertex() {
    // Timonen sec. 6: a bowl is the worst case of the hull tree. The stack
    // sweep pops every vertex at most once: pops <= vertices on any DEM.
    // Recorded (docs/BENCHMARKS.md): `cargo test --release --test horizons
    // bowl -- --nocapture`.
    for kind in [SynthKind::Bowl, SynthKind::Fractal, SynthKind::Noise] {
        let z = synth_grid(kind, 200, 200, 1);
        let t = Terrain::new(&z, 200, 200, 30.0, 30.0);
        let mut total = line::SweepStats::default();
        for band in plan_bands(Method::Line, 16, 30.0, 30.0, None) {
            let BandKind::Line(dir) = &band.kind else {
                unreachable!()
            };
            let mut out = vec![0f32; z.len()];
            let stats = line::line_horizons(&t, dir, &mut out);
            assert!(stats.pops <= stats.vertices, "{kind:?}: {stats:?}");
            assert_eq!(stats.posts, 200 * 200);
            total += stats;
        }
        eprintln!(
            "{kind:?}: per post and direction {:.2} hull pushes, {:.2} pops",
            total.vertices as f64 / total.posts as f64,
            total.pops as f64 / total.posts as f64
        );
        // Timonen's tree along every row (Table 2's m_a and t_a): the local
        // horizons of every post equal brute force, and the iterations stay
        // within his bound 2m + n (m: horizons, n: points).
        let (mut iterations, mut horizons, mut points) = (0u64, 0usize, 0usize);
        for row in 0..200 {
            let mut tree = HullTree::new();
            let mut profile = Vec::new();
            for col in 0..200 {
                // Timonen's worst case is a bowl with every other point
                // depressed: serrate the bowl.
                let dent = if kind == SynthKind::Bowl && col % 2 == 1 {
                    20.0
                } else {
                    0.0
                };
                let p = [col as f64 * 30.0, f64::from(z[row * 200 + col]) - dent];
                profile.push(p);
                tree.push(p[0], p[1]);
                if col > 0 {
                    let got = tree.horizons();
                    assert_eq!(
                        got,
                        local_horizons_brute(&profile),
                        "{kind:?} row {row} col {col}"
                    );
                    horizons += got.len();
                }
            }
            iterations += tree.iterations;
            points += 200;
        }
        eprintln!(
            "{kind:?} (serrated if a bowl): hull tree along rows: {:.2} local horizons and {:.2} iterations per point",
            horizons as f64 / points as f64,
            iterations as f64 / points as f64
        );
    }
}

#[test]
fn nodata_neither_occludes_nor_receives() {
    let (w, h) = (21, 15);
    let mut z = synth_grid(SynthKind::Fractal, w, h, 3);
    // A tall block, then the same block as nodata.
    let mut holed = z.clone();
    for row in 5..9 {
        for col in 10..14 {
            z[row * w + col] = 5000.0;
            holed[row * w + col] = f32::NAN;
        }
    }
    let t = Terrain::new(&holed, w, h, 30.0, 30.0);
    check_all("holes", &t);
    let tall = Terrain::new(&z, w, h, 30.0, 30.0);
    let band = &plan_bands(Method::Line, 4, 30.0, 30.0, None)[1]; // east
    let (with_block, _) = band_horizons(
        &tall,
        band,
        BandOptions {
            max_distance: None,
            narrow_check: true,
        },
    );
    let (with_hole, _) = band_horizons(
        &t,
        band,
        BandOptions {
            max_distance: None,
            narrow_check: true,
        },
    );
    let receiver = 6 * w + 4;
    assert!(with_block[receiver] > 60.0);
    assert!(with_hole[receiver] < with_block[receiver]);
    assert!(with_hole[6 * w + 11].is_nan());
}

#[test]
fn max_distance_cuts_the_horizon_where_it_should() {
    let z = synth_grid(SynthKind::Fractal, 60, 50, 9);
    let t = Terrain::new(&z, 60, 50, 30.0, 30.0);
    // Bounded line walks against the brute force with the same bound
    // (between crossings, so that rounding cannot flip one in or out), on a
    // square grid and a curved geographic one.
    let scale = geographic_scale(50, 60.0, 0.5);
    let geographic = Terrain::new(&z, 60, 50, 30.0, 25.0)
        .with_row_scale(RowScale::new(&scale))
        .with_curvature(curvature_coefficient(0.13));
    for (name, t) in [("square", t), ("geographic, curved", geographic)] {
        for band in plan_bands(Method::Line, 7, t.dx, t.dy, None) {
            let BandKind::Line(dir) = &band.kind else {
                unreachable!()
            };
            for max in [61.3, 301.7] {
                let opts = BandOptions {
                    max_distance: Some(max),
                    narrow_check: true,
                };
                let (walk, _) = band_horizons(&t, &band, opts);
                for (i, got) in walk.iter().enumerate() {
                    let (col, row) = (i % t.width, i / t.width);
                    let want = brute::line_horizon(&t, (col, row), dir.step, Some(max));
                    assert!(
                        same(*got, want, 1e-4),
                        "{name}: {:?} within {max} at ({col}, {row}): walk {got}, brute force {want}",
                        dir.step
                    );
                }
            }
        }
    }
    for band in plan_bands(Method::Line, 7, 30.0, 30.0, None) {
        let BandKind::Line(dir) = &band.kind else {
            unreachable!()
        };
        let (far, _) = band_horizons(
            &t,
            &band,
            BandOptions {
                max_distance: Some(1e9),
                narrow_check: true,
            },
        );
        let (all, _) = band_horizons(
            &t,
            &band,
            BandOptions {
                max_distance: None,
                narrow_check: true,
            },
        );
        let (near, _) = band_horizons(
            &t,
            &band,
            BandOptions {
                max_distance: Some(300.0),
                narrow_check: true,
            },
        );
        for i in 0..z.len() {
            assert!(same(far[i], all[i], 1e-4), "{:?} {i}", dir.step);
            assert!(near[i] <= all[i] + 1e-4);
        }
    }
}

#[test]
fn sector_within_a_distance_equals_brute_force_band_by_band() {
    use terrabake::algorithms::horizon::sector::sector_horizons_within;
    let (w, h) = (23, 19);
    let scale = geographic_scale(h, 60.0, 0.5);
    let noise = synth_grid(SynthKind::Noise, w, h, 2);
    let holes = synth_grid(SynthKind::Holes, w, h, 3);
    let fractal = synth_grid(SynthKind::Fractal, w, h, 4);
    let cases = [
        ("fractal", Terrain::new(&fractal, w, h, 30.0, 30.0)),
        (
            "noise, 30 x 20 m, curved",
            Terrain::new(&noise, w, h, 30.0, 20.0).with_curvature(curvature_coefficient(0.13)),
        ),
        (
            "holes, geographic",
            Terrain::new(&holes, w, h, 30.0, 25.0).with_row_scale(RowScale::new(&scale)),
        ),
    ];
    for (name, t) in cases {
        for count in COUNTS {
            let narrow = count >= 64;
            // Every sector up to 64; a spread of the 256.
            for index in (0..count).step_by(if count == 256 { 17 } else { 1 }) {
                let frame = SectorFrame::new(index, count, t.dx, t.dy);
                let stencil = narrow.then(|| NarrowStencil::new(&frame, count, t.dx, t.dy));
                let mut tree = vec![0f32; w * h];
                sector_horizons(&t, index, count, narrow, &mut tree);
                for max in [45.0, 200.0, 1e9] {
                    let mut got = vec![0f32; w * h];
                    sector_horizons_within(
                        &t,
                        (index, count),
                        narrow,
                        max,
                        [0..h, 0..w],
                        &mut got,
                        None,
                    );
                    for (i, &scan) in got.iter().enumerate() {
                        let (col, row) = (i % w, i / w);
                        let want = brute::sector_horizon(
                            &t,
                            (col, row),
                            &frame,
                            stencil.as_ref(),
                            Some(max),
                        );
                        assert!(
                            same(scan, want, 1e-4),
                            "{name}: sector {index}/{count} within {max} m at ({col}, {row}): scan {scan}, brute force {want}"
                        );
                        if max == 1e9 {
                            assert!(
                                same(scan, tree[i], 1e-4),
                                "{name}: past the DEM, the tree's"
                            );
                        }
                    }
                    // Bands of 4 rows from windows of the rows within reach:
                    // the same bits.
                    let halo = (max / t.dy).floor() as usize;
                    let mut banded = vec![0f32; w * h];
                    for r0 in (0..h).step_by(4) {
                        let band = r0..(r0 + 4).min(h);
                        let win = r0.saturating_sub(halo)..(band.end + halo).min(h);
                        let window = Terrain::window(
                            &t.z[win.start * w..win.end * w],
                            (w, h),
                            win.start,
                            (t.dx, t.dy),
                        )
                        .with_row_scale(t.row_scale)
                        .with_curvature(t.curvature);
                        let out = &mut banded[band.start * w..band.end * w];
                        sector_horizons_within(
                            &window,
                            (index, count),
                            narrow,
                            max,
                            [band, 0..w],
                            out,
                            None,
                        );
                    }
                    assert!(
                        banded
                            .iter()
                            .zip(&got)
                            .all(|(a, b)| common::same_heights(*a, *b)),
                        "{name}: sector {index}/{count} within {max} m by bands"
                    );
                }
            }
        }
    }
}

/// One post's sector horizon from a reach grown by the relief bound (the
/// planner's pilot) is the tree's over the whole DEM, on DEMs wider than
/// its first reach: terrains that stop the growth early (a bowl's rim),
/// late (a spike on a plain, seen from far), curved, with holes, and
/// geographic.
#[test]
fn one_posts_sector_horizon_from_its_grown_reach_is_the_trees() {
    use terrabake::algorithms::horizon::sector::sector_horizon_of_post;
    let (w, h) = (170, 150);
    let scale = geographic_scale(h, 62.0, 0.25);
    let grids: Vec<(SynthKind, Vec<f32>)> = [
        SynthKind::Fractal,
        SynthKind::Spike,
        SynthKind::Bowl,
        SynthKind::Holes,
    ]
    .into_iter()
    .map(|k| (k, synth_grid(k, w, h, 9)))
    .collect();
    for (i, (kind, z)) in grids.iter().enumerate() {
        let mut t = Terrain::new(z, w, h, 30.0, if i % 2 == 0 { 30.0 } else { 24.0 });
        if i == 1 {
            t = t.with_curvature(curvature_coefficient(0.13) * 400.0);
        }
        if i == 3 {
            t = t.with_row_scale(RowScale::new(&scale));
        }
        let top = z
            .iter()
            .filter(|v| !v.is_nan())
            .fold(f64::NEG_INFINITY, |m, &v| m.max(f64::from(v)));
        for count in [4, 16, 64] {
            let narrow = count >= 64;
            for index in (0..count).step_by(count / 4 + 1) {
                let mut tree = vec![0f32; w * h];
                sector_horizons(&t, index, count, narrow, &mut tree);
                for post in (0..w * h).step_by(97) {
                    let (col, row) = (post % w, post / w);
                    let got = sector_horizon_of_post(&t, (col, row), (index, count), narrow, top);
                    assert!(
                        same(got, tree[post], 1e-4),
                        "{kind:?}: sector {index}/{count} at ({col}, {row}): grown reach {got}, tree {}",
                        tree[post]
                    );
                }
            }
        }
    }
}

/// `sweep` over `whole` in bands of `rows` rows, each from its own window
/// of the DEM's rows, as the stage runs it out of core.
fn sweep_in_bands(sweep: &mut line::BandedSweep, whole: &Terrain, rows: usize) -> Vec<f32> {
    let w = whole.width;
    let mut out = vec![0f32; whole.z.len()];
    for band in sweep.bands(rows) {
        let win = sweep.window(&band);
        let window = Terrain::window(
            &whole.z[win.start * w..win.end * w],
            (w, whole.height),
            win.start,
            (whole.dx, whole.dy),
        )
        .with_row_scale(whole.row_scale)
        .with_curvature(whole.curvature);
        sweep.sweep(
            &window,
            band.clone(),
            &mut out[band.start * w..band.end * w],
        );
    }
    out
}

/// The line directions of 16 azimuths on `dx x dy` cells, and the grid
/// steps `extra` (long steps, many vertices each).
fn line_dirs(dx: f64, dy: f64, extra: &[(i64, i64)]) -> Vec<GridDirection> {
    let mut dirs: Vec<GridDirection> = plan_bands(Method::Line, 16, dx, dy, None)
        .into_iter()
        .map(|b| match b.kind {
            BandKind::Line(d) => d,
            _ => unreachable!(),
        })
        .collect();
    for &step in extra {
        let mut d = line::grid_direction(0.0, dx, dy, 1.0);
        d.step = step;
        dirs.push(d);
    }
    dirs
}

#[test]
fn line_sweeps_by_bands_equal_one_band() {
    use terrabake::algorithms::horizon::line::BandedSweep;
    // Out of core, a direction is swept over bands of rows with each line's
    // hull carried across: the result must not depend on the band height.
    let (w, h) = (41, 37);
    let mut z = synth_grid(SynthKind::Holes, w, h, 4);
    z[5 * w + 7] = f32::NAN;
    let (srtm, sdx, sdy) = common::srtm_crop((600, 400), (w as u32, h as u32));
    let scale = geographic_scale(h, 70.0, 1.0);
    for (name, z, dx, dy, curvature, row_scale) in [
        ("holes", &z, 30.0, 20.0, 0.0, RowScale::default()),
        (
            "SRTM crop, curved",
            &srtm,
            sdx,
            sdy,
            curvature_coefficient(0.13),
            RowScale::default(),
        ),
        (
            "holes, geographic",
            &z,
            30.0,
            20.0,
            0.0,
            RowScale::new(&scale),
        ),
    ] {
        let whole = Terrain::new(z, w, h, dx, dy)
            .with_row_scale(row_scale)
            .with_curvature(curvature);
        let dirs = line_dirs(dx, dy, &[(5, -13), (-7, 3), (3, 11)]);
        for dir in &dirs {
            let mut one = vec![0f32; w * h];
            line::line_horizons(&whole, dir, &mut one);
            for rows in [1, 2, 3, 7, 16, h] {
                let mut sweep =
                    BandedSweep::new(dir, (w, h), (dx, dy), row_scale, whole.has_nodata());
                let banded = sweep_in_bands(&mut sweep, &whole, rows);
                for i in 0..w * h {
                    assert!(
                        common::same_heights(one[i], banded[i]),
                        "{name}: {:?} bands of {rows}: post {i}: {} vs {}",
                        dir.step,
                        one[i],
                        banded[i]
                    );
                }
            }
        }
    }
}

/// The lines swept in SIMD lanes (`line::lanes`: AVX-512 and AVX2, each
/// the CPU runs) give the scalar sweep's bits, in one band and in bands of rows: every
/// direction of 16 and 64 and long steps, on terrains narrower than a
/// vector and wider than several, with curvature and geographic rows, and
/// on a dome whose hulls outgrow the lanes' depth (those lines leave the
/// lanes for the scalar sweep); with deep hulls and with shallow ones.
#[test]
fn line_lanes_equal_the_scalar_sweep_bit_for_bit() {
    use terrabake::algorithms::horizon::line::{grid_direction, BandedSweep};
    let cpu = line::lanes::cpu_has_lanes();
    let (srtm, sdx, sdy) = common::srtm_crop((500, 300), (83, 61));
    let scale = geographic_scale(61, 55.0, 1.0 / 1200.0);
    // A dome: every vertex of a concave profile stays on the hull.
    let dome: Vec<f32> = synth_grid(SynthKind::Bowl, 300, 40, 1)
        .iter()
        .map(|z| -z)
        .collect();
    let plain = RowScale::default();
    let (noise, fractal) = (
        synth_grid(SynthKind::Noise, 5, 9, 3),
        synth_grid(SynthKind::Fractal, 37, 29, 2),
    );
    // Name, heights, width, spacing, curvature, rows' scale.
    type Case<'a> = (&'a str, &'a [f32], usize, (f64, f64), f64, RowScale<'a>);
    let cases: Vec<Case> = vec![
        ("noise 5 x 9", &noise, 5, (30.0, 20.0), 0.0, plain),
        ("fractal 37 x 29", &fractal, 37, (30.0, 30.0), 0.0, plain),
        (
            "SRTM crop, curved",
            &srtm,
            83,
            (sdx, sdy),
            curvature_coefficient(0.13),
            plain,
        ),
        (
            "SRTM crop, geographic",
            &srtm,
            83,
            (sdx, sdy),
            curvature_coefficient(0.13),
            RowScale::new(&scale),
        ),
        ("dome 300 x 40", &dome, 300, (30.0, 30.0), 0.0, plain),
    ];
    let (mut in_lanes, mut spilled) = (0, false);
    for &(name, z, w, (dx, dy), curvature, row_scale) in &cases {
        let h = z.len() / w;
        let mut dirs: Vec<GridDirection> = [16, 64]
            .into_iter()
            .flat_map(|count| plan_bands(Method::Line, count, dx, dy, None))
            .map(|b| match b.kind {
                BandKind::Line(d) => d,
                _ => unreachable!(),
            })
            .collect();
        // Long steps too (46 and 66 vertices, the planner's kind).
        for step in [(5, -13), (-7, 3), (3, 11), (-1, 1), (17, 7), (-25, 9)] {
            let mut d = grid_direction(0.0, dx, dy, 1.0);
            d.step = step;
            dirs.push(d);
        }
        for dir in &dirs {
            let new = || BandedSweep::new(dir, (w, h), (dx, dy), row_scale, false);
            let mut scalar = new().without_lanes();
            let whole = Terrain::new(z, w, h, dx, dy)
                .with_row_scale(row_scale)
                .with_curvature(curvature);
            let mut want = vec![0f32; w * h];
            scalar.sweep(&whole, 0..h, &mut want);
            let short = line::Stencil::new(dir.step).len() + line::lanes::HEADROOM
                <= line::lanes::MAX_DEPTH;
            // East-west steps go in lanes of rows (`lanes::Rows`).
            assert_eq!(new().in_lanes(), cpu && short, "{name}: {:?}", dir.step);
            assert!(!new().with_lane_memory(0).in_lanes());
            // Every kind of lanes the CPU runs; bands of rows; hulls as deep
            // as the lanes go, and shallower (64 KiB a direction: 32
            // vertices or none on these widths).
            let kinds: Vec<_> = terrabake::plumbing::simd::available()
                .into_iter()
                .filter(|&l| l > terrabake::plumbing::simd::Level::Scalar)
                .collect();
            let runs = [(1, None), (7, None), (h, None), (7, Some(64 << 10))];
            for (kind, (rows, memory)) in kinds.iter().flat_map(|&k| runs.map(|r| (k, r))) {
                let mut sweep = match memory {
                    Some(bytes) => new().with_lanes(kind).with_lane_memory(bytes),
                    None => new().with_lanes(kind),
                };
                in_lanes += usize::from(sweep.in_lanes());
                let got = sweep_in_bands(&mut sweep, &whole, rows);
                assert_eq!(
                    sweep.stats.posts, scalar.stats.posts,
                    "{name}: {:?}, {kind:?}",
                    dir.step
                );
                assert_eq!(sweep.stats.vertices, scalar.stats.vertices);
                // And pop exactly the vertices the scalar sweep pops.
                assert_eq!(sweep.stats.pops, scalar.stats.pops);
                spilled |= sweep.stats.spilled > 0;
                for i in 0..w * h {
                    assert!(
                        common::same_heights(want[i], got[i]),
                        "{name}: {:?}, {kind:?}, bands of {rows}, lanes memory {memory:?}: post ({}, {}): scalar {} vs lanes {}",
                        dir.step,
                        i % w,
                        i / w,
                        want[i],
                        got[i]
                    );
                }
            }
        }
    }
    eprintln!(
        "{in_lanes} sweeps in lanes ({:?})",
        terrabake::plumbing::simd::available()
    );
    assert_eq!(in_lanes > 0, cpu);
    // The dome's long lines left the lanes.
    assert_eq!(spilled, cpu);
}

/// Stewart's tree above its 128-rank buckets: on DEMs of more than 10^5
/// posts every level of the tree is built and walked, where the whole-DEM
/// tests above (at most 480 posts) barely leave the buckets. Sampled posts
/// (the brute force is O(n) a post), every sector, with and without the
/// narrow check, on a fractal and on non-square cells of rolling terrain.
#[test]
fn the_sector_tree_equals_brute_force_above_its_buckets() {
    let mut seed = 0x7ee_u64;
    let mut next = |n: usize| {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 33) as usize % n
    };
    for (kind, (w, h), (dx, dy), counts) in [
        (SynthKind::Fractal, (360, 300), (30.0, 30.0), [16, 5]),
        (SynthKind::Sine, (420, 250), (25.0, 40.0), [12, 7]),
    ] {
        assert!(w * h > 100_000);
        let z = synth_grid(kind, w, h, 17);
        let t = Terrain::new(&z, w, h, dx, dy);
        // Corners and edges, then posts anywhere.
        let mut posts = vec![
            (0, 0),
            (w - 1, 0),
            (0, h - 1),
            (w - 1, h - 1),
            (w / 2, 0),
            (0, h / 2),
        ];
        posts.extend((0..60).map(|_| (next(w), next(h))));
        for (c, count) in counts.into_iter().enumerate() {
            let narrow = c == 0;
            for index in 0..count {
                let mut out = vec![0f32; w * h];
                sector_horizons(&t, index, count, narrow, &mut out);
                let frame = SectorFrame::new(index, count, dx, dy);
                let stencil = narrow.then(|| NarrowStencil::new(&frame, count, dx, dy));
                for &(col, row) in &posts {
                    let got = out[row * w + col];
                    let want =
                        brute::sector_horizon(&t, (col, row), &frame, stencil.as_ref(), None);
                    assert!(
                        same(got, want, 1e-4),
                        "{kind:?} {w} x {h}: sector {index}/{count} (narrow {narrow}) at ({col}, {row}): tree {got}, brute force {want}"
                    );
                }
            }
        }
    }
}

/// Stewart's tree gives the same bits, angles and distances, with its
/// hulls in every store this CPU runs (one array for every node in AVX-512
/// and AVX2 code, a vector each in scalar code), and with its sorted orders handed on
/// from sector to sector (`Ranks`): every other sector of 64 (the narrow check
/// on), a spread of 16 and all of 4 (their boundaries on the grid's
/// diagonals, where posts tie), on a fractal of more than 100,000 posts
/// with curvature, and on a dome, whose every post is on its hulls, so
/// that they outgrow the array and move to vectors. Ranks sorted on
/// another grid with as many posts are left unused; the opposite sector's
/// ranks read backwards are used. The sorts and sweeps handed on share one
/// room (`Scratch`), whatever the last one left in it.
#[test]
fn the_sector_tree_gives_the_same_bits_in_every_store_and_shared() {
    use terrabake::algorithms::horizon::sector::{
        sector_horizons_at, DataPosts, Ranks, Scratch, Shared,
    };
    use terrabake::plumbing::simd::Level;
    let levels = terrabake::plumbing::simd::available();
    let widest = *levels.last().unwrap();
    let fractal = synth_grid(SynthKind::Fractal, 400, 260, 5);
    let dome: Vec<f32> = synth_grid(SynthKind::Bowl, 240, 160, 1)
        .iter()
        .map(|z| -z)
        .collect();
    let cases = [
        (
            "fractal 400 x 260, curved",
            &fractal,
            400,
            (30.0, 30.0),
            0.13,
        ),
        ("dome 240 x 160", &dome, 240, (30.0, 20.0), 1.0),
    ];
    // One room for every sort and sweep: each finds what the one before
    // left, from a larger grid or a smaller.
    let room = Scratch::default();
    for (name, z, w, (dx, dy), k) in cases {
        let h = z.len() / w;
        let t = Terrain::new(z, w, h, dx, dy).with_curvature(curvature_coefficient(k));
        for (count, every) in [(64, 2), (16, 3), (4, 1)] {
            let posts = DataPosts::of(&t);
            let ranks: Vec<Ranks> = (0..count)
                .map(|i| Ranks::of_in(&t, &posts, (i, count), &room))
                .collect();
            for index in (0..count).step_by(every) {
                let run = |level, shared| {
                    let (mut angles, mut metres) = (vec![0f32; w * h], vec![0f32; w * h]);
                    sector_horizons_at(
                        &t,
                        (index, count),
                        count == 64,
                        (level, shared),
                        &mut angles,
                        Some(&mut metres),
                    );
                    let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
                    (bits(angles), bits(metres))
                };
                let want = run(Level::Scalar, Shared::default());
                for &level in &levels[1..] {
                    assert!(
                        run(level, Shared::default()) == want,
                        "{name}: sector {index}/{count}: {level:?} differs from scalar code"
                    );
                }
                let shared = Shared {
                    posts: Some(&posts),
                    ranks: Some(&ranks[index]),
                    previous: Some(&ranks[(index + count - 1) % count]),
                    scratch: Some(&room),
                };
                assert!(
                    run(widest, shared) == want,
                    "{name}: sector {index}/{count}: the orders handed on differ"
                );
                // And the opposite sectors' ranks read backwards.
                let opposite = |i: usize| ranks[(i + count / 2) % count].opposite().unwrap();
                let (mine, before) = (opposite(index), opposite((index + count - 1) % count));
                let shared = Shared {
                    posts: Some(&posts),
                    ranks: Some(&mine),
                    previous: Some(&before),
                    scratch: Some(&room),
                };
                assert!(
                    run(widest, shared) == want,
                    "{name}: sector {index}/{count}: the opposite sector's orders differ"
                );
                // Ranks of another grid with as many posts (its rows and
                // columns swapped) are not used.
                if index % 8 == 0 {
                    let other = Terrain::new(z, h, w, dx, dy);
                    let other_posts = DataPosts::of(&other);
                    let foreign = Ranks::of(&other, &other_posts, (index, count));
                    let shared = Shared {
                        posts: Some(&other_posts),
                        ranks: Some(&foreign),
                        previous: Some(&foreign),
                        scratch: None,
                    };
                    assert!(
                        run(widest, shared) == want,
                        "{name}: sector {index}/{count}: another grid's orders were used"
                    );
                }
            }
        }
    }
}

/// The walk that stops where the DEM's highest post can no longer rise
/// above the horizon so far, and steps over the blocks whose highest post
/// cannot, keeps every record of the whole walk, on every synthetic
/// terrain (holes included), flat and curved, in grid directions of every
/// kind, on a geographic grid, with blocks of one size or several (a block
/// of one cell included) or none; and the blocks spare crossings.
#[test]
fn records_stopped_at_the_relief_bound_equal_the_whole_walk() {
    let (w, h) = (57, 43);
    let steps = [(0, -1), (1, 0), (1, 1), (2, -5), (-3, 7), (5, 2), (-1, -4)];
    let sizes: [&[usize]; 4] = [&[], &[1], &[4], &[16, 4, 2]];
    let (mut compared, mut stops) = (0, 0);
    let mut walked = [0; 4];
    for kind in SynthKind::ALL {
        let z = synth_grid(kind, w, h, 11);
        let scale = geographic_scale(h, 61.0, 0.01);
        let flat = Terrain::new(&z, w, h, 30.0, 25.0);
        let curved = flat.with_curvature(curvature_coefficient(0.13));
        let geographic = Terrain::new(&z, w, h, 30.0, 25.0)
            .with_row_scale(RowScale::new(&scale))
            .with_curvature(curvature_coefficient(0.13));
        for (i, t) in [&flat, &curved, &geographic].into_iter().enumerate() {
            let blocks = sizes.map(|s| brute::BlockMax::of(t, s));
            let z_max = blocks[0].top;
            for post in [(0, 0), (28, 21), (56, 42), (3, 39), (40, 5)] {
                for &step in &steps {
                    let whole = brute::line_horizon_records(t, post, step);
                    for (k, heights) in blocks.iter().enumerate() {
                        let (stopped, looked) =
                            brute::line_horizon_records_walked(t, post, step, heights);
                        assert_eq!(
                            stopped, whole,
                            "{kind:?} post {post:?} step {step:?} blocks {:?}",
                            sizes[k]
                        );
                        walked[k] += looked;
                    }
                    compared += whole.len();
                    // Lines whose bound at the DEM's edge is under their
                    // horizon (uniform grids): the walk stopped before it.
                    let (Some(last), true) = (whole.last(), i < 2) else {
                        continue;
                    };
                    let exit = |p: usize, d: i64, n: usize| match d.signum() {
                        1 => (n - 1 - p) as f64 / d as f64,
                        -1 => p as f64 / -d as f64,
                        _ => f64::INFINITY,
                    };
                    let s = exit(post.0, step.0, w).min(exit(post.1, step.1, h));
                    let end = s * (step.0 as f64 * 30.0).hypot(step.1 as f64 * 25.0);
                    let rise = z_max - f64::from(z[post.1 * w + post.0]);
                    let slope = f64::from(last.angle).to_radians().tan();
                    if rise / end - t.curvature * end < slope - 1e-6 {
                        stops += 1;
                    }
                }
            }
        }
    }
    assert!(compared > 1000, "{compared} records compared");
    assert!(stops > 20, "{stops} lines stop before the edge");
    // Every size of block looks at fewer crossings than the stop alone.
    for k in 1..4 {
        assert!(walked[k] < walked[0], "blocks {:?}: {walked:?}", sizes[k]);
    }
}

/// Reliability, third round, failure 16: on a curved earth a flat sea is a
/// string of hull vertices that never pop, and the sweep's memory grew
/// with the square of the side. Told the DEM's highest post, each line
/// drops the far vertices no post to come can see: the hull of a flat
/// curved sea stays a few vertices, and on random terrains under a strong
/// curvature (where trims happen every few steps) the angles keep the
/// untrimmed sweep's bits, scalar and in lanes, in one band and in many.
#[test]
fn trimmed_hulls_keep_the_bits_and_bound_a_curved_sea() {
    use terrabake::algorithms::horizon::line::{grid_direction, BandedSweep};
    let plain = RowScale::default();
    // A flat sea 45 km long, 30 m posts, the earth's curvature with
    // refraction: each hull keeps a few vertices, whatever the DEM's size.
    let (w, h) = (120, 1500);
    let sea = vec![0f32; w * h];
    let terrain = Terrain::new(&sea, w, h, 30.0, 30.0).with_curvature(curvature_coefficient(0.13));
    for step in [(0, -1), (0, 1), (1, -20)] {
        let mut dir = grid_direction(0.0, 30.0, 30.0, 1.0);
        dir.step = step;
        let new = || BandedSweep::new(&dir, (w, h), (30.0, 30.0), plain, false).without_lanes();
        let (mut kept, mut trimmed) = (new(), new().with_height_bound(0.0));
        let (mut a, mut b) = (vec![0f32; w * h], vec![0f32; w * h]);
        kept.sweep(&terrain, 0..h, &mut a);
        trimmed.sweep(&terrain, 0..h, &mut b);
        assert!(
            a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{:?}",
            dir.step
        );
        assert!(
            kept.stats.longest_hull > 1400,
            "{:?}: {}",
            dir.step,
            kept.stats.longest_hull
        );
        assert!(
            trimmed.stats.longest_hull <= 32,
            "{:?}: {}",
            dir.step,
            trimmed.stats.longest_hull
        );
    }
    // Random terrains, a curvature a million times the earth's: heights of
    // tens of metres hide what lies past a few hundred metres.
    let mut trims = 0;
    for (seed, kind) in [
        (1, SynthKind::Fractal),
        (2, SynthKind::Noise),
        (3, SynthKind::Holes),
    ] {
        let (w, h) = (150, 130);
        let z: Vec<f32> = synth_grid(kind, w, h, seed)
            .iter()
            .map(|v| v * 40.0)
            .collect();
        let highest = z.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let (dx, dy) = (7.0, 5.0);
        let terrain = Terrain::new(&z, w, h, dx, dy).with_curvature(2e-3);
        let nodata = terrain.has_nodata();
        for dir in line_dirs(dx, dy, &[(5, -13), (-7, 3), (17, 7)]) {
            let new = || BandedSweep::new(&dir, (w, h), (dx, dy), plain, nodata);
            let mut want = vec![0f32; w * h];
            let mut kept = new().without_lanes();
            kept.sweep(&terrain, 0..h, &mut want);
            for lanes in [false, true] {
                for rows in [h, 16, 3] {
                    let mut sweep = new().with_height_bound(f64::from(highest));
                    if !lanes {
                        sweep = sweep.without_lanes();
                    }
                    let got = sweep_in_bands(&mut sweep, &terrain, rows);
                    for i in 0..w * h {
                        assert!(
                            common::same_heights(want[i], got[i]),
                            "{kind:?} {:?} lanes {lanes} bands of {rows}: post {i}: {} vs {}",
                            dir.step,
                            want[i],
                            got[i]
                        );
                    }
                    if sweep.stats.longest_hull < kept.stats.longest_hull {
                        trims += 1;
                    }
                }
            }
        }
    }
    assert!(trims > 20, "trims shortened only {trims} sweeps' hulls");
}

/// A horizon layer's features (`terrabake_format::features`) are exact: the
/// horizon of a sight line is the larger of the features' horizon (the
/// crossings with the six segments that meet at each feature post) and the
/// horizon of the same terrain with each feature lowered to its highest
/// neighbour. Checked against the brute-force reference on the spike plain
/// and on a fractal with masts (one within 90 posts of another), with
/// curvature, at every third post and 360 azimuths off the grid
/// directions; the features set the horizon at some of them, by degrees.
#[test]
fn a_features_horizon_and_the_terrain_without_it_make_the_exact_horizon() {
    use terrabake::algorithms::horizon::features::spikes_in_rows;
    use terrabake_format::features::{HorizonFeatures, SightLine};

    let (w, h, spacing) = (64, 48, 30.0);
    let masts: &[(usize, usize, f32)] = &[(20, 30, 400.0), (50, 10, 150.0), (8, 5, 200.0)];
    for (name, kind, raised) in [
        ("spike", SynthKind::Spike, &[][..]),
        ("fractal with masts", SynthKind::Fractal, masts),
    ] {
        let mut z = synth_grid(kind, w, h, 7);
        for &(x, y, up) in raised {
            z[y * w + x] += up;
        }
        let curvature = curvature_coefficient(0.13);
        let t = Terrain::new(&z, w, h, spacing, spacing).with_curvature(curvature);
        let mut spikes = Vec::new();
        spikes_in_rows(&t, 0..h, 50.0, 16, &mut spikes);
        assert_eq!(spikes.len(), 1.max(raised.len()), "{name}: {spikes:?}");
        let features = HorizonFeatures {
            curvature,
            max_distance: None,
            posts: spikes.iter().map(|s| s.post).collect(),
        };
        let mut lowered = z.clone();
        for s in &spikes {
            lowered[s.post.y as usize * w + s.post.x as usize] -= s.rise;
        }
        let tl = Terrain::new(&lowered, w, h, spacing, spacing).with_curvature(curvature);
        let exact = |t: &Terrain, post, az| {
            brute::ray_horizon_records(t, post, az)
                .last()
                .map_or(-90.0, |r| f64::from(r.angle))
        };
        let (mut compared, mut set_by_features) = (0, 0);
        for y in (0..h).step_by(3) {
            for x in (0..w).step_by(3) {
                if spikes
                    .iter()
                    .any(|s| (s.post.x, s.post.y) == (x as u32, y as u32))
                {
                    continue; // Its own eye was lowered.
                }
                for k in 0..360 {
                    let az = k as f64 + 0.37;
                    let line = SightLine::new(
                        (x as u32, y as u32),
                        f64::from(z[y * w + x]),
                        az,
                        (spacing, spacing),
                    );
                    let feature = features.horizon(&line).unwrap_or(-90.0);
                    let without = exact(&tl, (x, y), az);
                    let truth = exact(&t, (x, y), az);
                    assert!(
                        (feature.max(without) - truth).abs() < 1e-4,
                        "{name}: post ({x}, {y}), azimuth {az}: features {feature}, lowered {without}, exact {truth}"
                    );
                    compared += 1;
                    set_by_features += usize::from(feature > without + 1.0);
                }
            }
        }
        assert!(
            set_by_features > 100,
            "{name}: {set_by_features} of {compared}"
        );
        eprintln!("{name}: the features set {set_by_features} of {compared} horizons by more than a degree");
    }
}

/// Over about 800 line bands the grid has no step between north and 0.9
/// degrees either side of it (steps of up to `MAX_STEP` posts), so the last
/// nominal azimuths fall back to the step at 0 and several bands share a
/// step. The bands stay in compass order, and the loader serves every
/// azimuth linearly between the nearest band at or before it and the next
/// one after it (cyclically), found here by a scan rather than bisection:
/// before, the bands ended with a band at 0 after 359.1, and the last 0.9
/// degrees were served one band's angle flat, up to 19 degrees off on a
/// lidar DSM. A manifest out of compass order is refused.
#[test]
fn many_line_bands_stay_in_compass_order_and_serve_across_north() {
    let bands = plan_bands(Method::Line, 1440, 30.0, 30.0, None);
    let azimuths: Vec<f64> = bands.iter().map(|b| b.azimuth).collect();
    // Several asked azimuths fall back to the step at 0: baked once.
    assert!(azimuths.windows(2).all(|p| p[0] < p[1]), "{azimuths:?}");
    assert_eq!(azimuths.iter().filter(|&&a| a == 0.0).count(), 1);
    assert!(bands.len() < 1440);

    let dir = tempfile::tempdir().unwrap();
    let (tif, asset) = (dir.path().join("f.tif"), dir.path().join("f.tbake"));
    let (tif, asset) = (tif.to_str().unwrap(), asset.to_str().unwrap());
    for args in [
        &["synth", "fractal", "--size", "40x32", "-o", tif, "-q"][..],
        &["ingest", tif, "-o", asset, "-q"],
        &["horizons", asset, "--sectors", "1440", "-q"],
    ] {
        let o = common::terrabake(args);
        assert!(o.status.success(), "{args:?}: {}", common::stderr(&o));
    }
    let a = terrabake_format::Asset::open(asset).unwrap();
    let map = terrabake_format::horizons::HorizonMap::open(&a).unwrap();
    let az = map.azimuths().to_vec();
    assert!(az.windows(2).all(|p| p[0] <= p[1]));
    let last = *az.last().unwrap();
    assert!(last < 359.5, "the last band at {last}");
    for (x, y) in [(20, 16), (5, 27), (33, 3)] {
        let angle = |k: usize| map.angle(x, y, k as u32).unwrap().unwrap();
        for i in 0..5143 {
            let q = i as f64 * 0.07;
            // The band at or before q and the band after it, cyclically.
            let before = (0..az.len())
                .rev()
                .find(|&k| az[k] <= q)
                .unwrap_or(az.len() - 1);
            let after = (0..az.len()).find(|&k| az[k] > q).unwrap_or(0);
            let span = (az[after] - az[before]).rem_euclid(360.0);
            let f = (q - az[before]).rem_euclid(360.0) / span;
            let want = angle(before) + f * (angle(after) - angle(before));
            let got = map.horizon_at(x, y, q).unwrap().unwrap();
            assert!(
                (got - want).abs() < 1e-9,
                "post ({x}, {y}) at {q:.2}: served {got}, bands {} at {} and {} at {}",
                angle(before),
                az[before],
                angle(after),
                az[after]
            );
        }
    }

    let path = std::path::Path::new(asset).join("manifest.tba");
    let bytes = std::fs::read(&path).unwrap();
    let mut json: serde_json::Value = serde_json::from_slice(&bytes[32..]).unwrap();
    for layer in json["layers"].as_array_mut().unwrap() {
        if layer["name"] == "horizon" {
            layer["band_azimuths"][az.len() - 1] = 0.0.into();
        }
    }
    let manifest: terrabake_format::Manifest = serde_json::from_value(json).unwrap();
    let err = manifest.validate().unwrap_err();
    assert!(
        err.contains(&format!("out of compass order: band {} at 0", az.len() - 1)),
        "{err}"
    );
}

/// A line band is a grid step, baked once: where neighbouring asked
/// azimuths fall back to one step (near the axes past about 800
/// directions; sooner on cells of 50 x 93 m), the band is not repeated,
/// the azimuths rise strictly (the xarray backend's coordinate), and the
/// bands' intervals still cover the circle once.
#[test]
fn line_bands_bake_each_grid_step_once() {
    for (count, dx, dy, repeats) in [
        (1440, 1.0, 1.0, true),
        (720, 50.0, 93.0, true),
        (16, 30.0, 30.0, false),
        (360, 30.0, 30.0, false),
    ] {
        let bands = plan_bands(Method::Line, count, dx, dy, None);
        let steps: Vec<(i64, i64)> = bands
            .iter()
            .map(|b| match &b.kind {
                BandKind::Line(d) => d.step,
                other => panic!("{other:?}"),
            })
            .collect();
        let mut distinct = steps.clone();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(distinct.len(), steps.len(), "{count} on {dx} x {dy}");
        assert_eq!(
            bands.len() < count,
            repeats,
            "{count} on {dx} x {dy}: {}",
            bands.len()
        );
        assert!(
            bands.windows(2).all(|w| w[0].azimuth < w[1].azimuth),
            "{count} on {dx} x {dy}"
        );
        let covered: f64 = bands.iter().map(|b| b.hi - b.lo).sum();
        assert!((covered - 360.0).abs() < 1e-9, "{count}: {covered}");
    }
}
