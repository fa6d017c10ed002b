//! Every tracer against the brute force, on every synthetic terrain and a
//! crop of the real DEM: 200,000 rays per method per terrain in `make
//! test`, one million in `make test-full` (TERRABAKE_TRACE_RAYS), mixing
//! random rays with the cases where tracers fail: axis-parallel rays (also
//! exactly along grid lines), exact
//! diagonals through cell corners, grazing rays that touch a post's top,
//! rays starting below the surface, outside the box, on tile borders,
//! straight up and down, and through nodata holes. The bar is zero
//! mismatches.
//!
//! A hit matches when `t` agrees within 1e-5 (relative) and the cell is the
//! same, or, when the hit point lies on an edge or corner shared by several
//! cells, another cell that also holds that point.

mod common;

use std::path::Path;

use rayon::prelude::*;
use terrabake::io::source::{ByteOrder, RawSampleType, RawSpec};
use terrabake::io::synth::SynthKind;
use terrabake::plumbing::progress::Progress;
use terrabake::stage::run_stage;
use terrabake::stages::cones::{ConesStage, SliceChoice};
use terrabake::stages::ingest::{ingest, IngestOptions};
use terrabake::stages::pyramid::PyramidStage;
use terrabake_format::cones::ConeEncoding;
use terrabake_format::surface::GridRay;
use terrabake_format::trace::{Hit, Method, Ray, Tracer};
use terrabake_format::{Asset, Mmap};

/// SplitMix64: deterministic, seedable, good enough for test rays.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.unit()
    }
    fn int(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

fn rays_per_terrain() -> usize {
    std::env::var("TERRABAKE_TRACE_RAYS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(200_000)
}

/// The cone planes of the `n`-th terrain: every slice choice and encoding
/// in turn, so that the matrix covers them all.
fn cones_stage(n: usize) -> ConesStage {
    let slices = [
        SliceChoice::Exact,
        SliceChoice::Count(16),
        SliceChoice::Auto,
        SliceChoice::Count(1),
        SliceChoice::Count(300),
    ];
    ConesStage {
        slices: slices[n % slices.len()],
        encoding: ConeEncoding::ALL[n % 3],
        ..Default::default()
    }
}

/// A terrain asset with a pyramid and cone planes: posts `w x h`, tiles of
/// 16, cells of `dx x dy` m.
fn build_asset(
    dir: &Path,
    src: &Path,
    raw: Option<RawSpec>,
    cell: (f64, f64),
    n: usize,
) -> Asset<Mmap> {
    let out = dir.join("t.tbake");
    let opts = IngestOptions {
        tile_size: 16,
        cell_size: Some(cell),
        ..raw.map(IngestOptions::for_raw).unwrap_or_default()
    };
    ingest(src, &out, &opts, Progress::hidden()).unwrap();
    run_stage(&out, &PyramidStage, false, Progress::hidden()).unwrap();
    run_stage(&out, &cones_stage(n), false, Progress::hidden()).unwrap();
    Asset::open(&out).unwrap()
}

fn synth_asset(dir: &Path, kind: SynthKind, w: u32, h: u32, n: usize) -> Asset<Mmap> {
    let opts = IngestOptions {
        tile_size: 16,
        cell_size: Some((30.0, 20.0)),
        ..Default::default()
    };
    let out = common::synth_with_pyramid(dir, kind, w, h, 11, opts);
    run_stage(&out, &cones_stage(n), false, Progress::hidden()).unwrap();
    Asset::open(out).unwrap()
}

/// A ray of one of the hard kinds, in local metres.
fn make_ray(rng: &mut Rng, tracer: &Tracer<'_, Mmap>, asset: &Asset<Mmap>) -> Ray {
    let (xm, ym) = tracer.extent();
    let m = asset.manifest();
    let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
    let range = m
        .height_range
        .map_or((0.0, 1.0), |r| (f64::from(r.min), f64::from(r.max)));
    let zspan = (range.1 - range.0).max(1.0);
    let height = asset.height().unwrap();
    let post_z = |col: u32, row: u32| height.height_at(col, row).unwrap();
    let (w, h) = (height.width(), height.height());
    let any_dir = |rng: &mut Rng| {
        let z: f64 = rng.range(-1.0, 1.0);
        let phi = rng.range(0.0, std::f64::consts::TAU);
        let s = (1.0 - z * z).sqrt();
        [s * phi.cos() * 1000.0, s * phi.sin() * 1000.0, z * zspan]
    };
    let inside = |rng: &mut Rng| {
        [
            rng.range(0.0, xm),
            rng.range(0.0, ym),
            rng.range(range.0, range.1 + 0.5 * zspan),
        ]
    };
    let ray = |origin, dir| Ray {
        origin,
        dir,
        t_min: 0.0,
        t_max: f64::INFINITY,
    };
    match rng.int(12) {
        // Random rays from inside and around the box.
        0 | 1 => ray(inside(rng), any_dir(rng)),
        2 => {
            let o = [
                rng.range(-0.5 * xm, 1.5 * xm),
                rng.range(-0.5 * ym, 1.5 * ym),
                rng.range(range.0 - zspan, range.1 + 2.0 * zspan),
            ];
            // Aim at a random point of the box so most of these enter it.
            let target = inside(rng);
            ray(
                o,
                [
                    target[0] - o[0],
                    target[1] - o[1],
                    target[2] - o[2] - zspan * rng.unit(),
                ],
            )
        }
        // Axis-parallel, sometimes exactly along a grid line.
        3 => {
            let mut o = inside(rng);
            let along_x = rng.int(2) == 0;
            if rng.int(2) == 0 {
                if along_x {
                    o[1] = f64::from(rng.int(u64::from(h)) as u32) * dy;
                } else {
                    o[0] = f64::from(rng.int(u64::from(w)) as u32) * dx;
                }
            }
            let s = if rng.int(2) == 0 { 1.0 } else { -1.0 };
            let dz = rng.range(-0.2, 0.05) * zspan / 100.0;
            ray(
                o,
                if along_x {
                    [s * 100.0, 0.0, dz]
                } else {
                    [0.0, s * 100.0, dz]
                },
            )
        }
        // Exact diagonals through posts (cell corners).
        4 => {
            let (c, r) = (rng.int(u64::from(w)) as f64, rng.int(u64::from(h)) as f64);
            let o = [c * dx, r * dy, range.1 + rng.range(0.0, 0.3) * zspan];
            let (sx, sy) = (
                if rng.int(2) == 0 { 1.0 } else { -1.0 },
                if rng.int(2) == 0 { 1.0 } else { -1.0 },
            );
            ray(o, [sx * dx, sy * dy, -rng.range(0.0, 0.05) * zspan])
        }
        // Grazing: passes exactly over a post's top (touching it) at t = 1.
        5 => {
            let (c, r) = (rng.int(u64::from(w)) as u32, rng.int(u64::from(h)) as u32);
            let Some(z) = post_z(c, r) else {
                return ray(inside(rng), any_dir(rng));
            };
            let top = [f64::from(c) * dx, f64::from(h - 1 - r) * dy, f64::from(z)];
            let phi = rng.range(0.0, std::f64::consts::TAU);
            let len = rng.range(5.0, 40.0) * dx;
            let d = [
                phi.cos() * len,
                phi.sin() * len,
                rng.range(-0.001, 0.001) * zspan,
            ];
            ray([top[0] - d[0], top[1] - d[1], top[2] - d[2]], d)
        }
        // Starting below the surface.
        6 => {
            let (c, r) = (rng.int(u64::from(w)) as u32, rng.int(u64::from(h)) as u32);
            let z = post_z(c, r).map_or(range.0, f64::from) - rng.range(0.1, 50.0);
            ray(
                [f64::from(c) * dx, f64::from(h - 1 - r) * dy, z],
                any_dir(rng),
            )
        }
        // On a tile border (posts 16, 32, ...).
        7 => {
            let mut o = inside(rng);
            o[0] = 16.0 * (rng.int(u64::from(w / 16 + 1)) as f64) * dx;
            ray(o, any_dir(rng))
        }
        // Straight up and straight down, anywhere including grid lines and corners.
        8 => {
            let mut o = inside(rng);
            if rng.int(2) == 0 {
                o[0] = rng.int(u64::from(w)) as f64 * dx;
            }
            if rng.int(2) == 0 {
                o[1] = rng.int(u64::from(h)) as f64 * dy;
            }
            o[2] = range.1 + 10.0;
            let up = rng.int(4) == 0;
            if up {
                o[2] = range.0 - 10.0 + rng.range(0.0, zspan);
            }
            ray(o, [0.0, 0.0, if up { 1.0 } else { -1.0 }])
        }
        // Shallow rays, the oblique views of a renderer.
        9 | 10 => {
            let o = [
                rng.range(0.0, xm),
                rng.range(0.0, ym),
                range.1 + rng.range(0.0, 0.5) * zspan,
            ];
            let phi = rng.range(0.0, std::f64::consts::TAU);
            ray(
                o,
                [
                    phi.cos() * 1000.0,
                    phi.sin() * 1000.0,
                    -rng.range(0.0, 0.1) * zspan,
                ],
            )
        }
        // A bounded segment (t_max), as shadow rays are.
        _ => {
            let mut r = ray(inside(rng), any_dir(rng));
            r.t_min = rng.range(0.0, 0.5);
            r.t_max = rng.range(0.5, 3.0);
            r
        }
    }
}

/// Whether `hit` matches the reference `want` (see the module docs).
fn same_hit(tracer: &Tracer<'_, Mmap>, ray: &Ray, hit: &Option<Hit>, want: &Option<Hit>) -> bool {
    match (hit, want) {
        (None, None) => true,
        (Some(a), Some(b)) => {
            let tol = 1e-5 * b.t.abs().max(1.0);
            if (a.t - b.t).abs() > tol {
                return false;
            }
            if a.cell == b.cell {
                return true;
            }
            // Both cells must hold the hit point.
            let g: GridRay = tracer.grid_ray(ray);
            let holds = |(c, r): (u32, u32)| {
                let (t0, t1) = g.square(
                    f64::from(c),
                    f64::from(r),
                    1.0,
                    f64::NEG_INFINITY,
                    f64::INFINITY,
                );
                t0 - tol <= b.t && b.t <= t1 + tol
            };
            holds(a.cell) && holds(b.cell)
        }
        _ => false,
    }
}

/// Traces `n` rays with every method and returns mismatches per method,
/// with the first few for the failure message, and hit counts.
fn check_terrain(name: &str, asset: &Asset<Mmap>, n: usize, seed: u64) {
    let tracer = Tracer::new(asset).unwrap();
    assert!(tracer.has_pyramid() && tracer.has_cones());
    let methods = [
        Method::Incremental,
        Method::Runs,
        Method::Hierarchical,
        Method::Parametric,
    ];
    let chunks = 64;
    let results: Vec<(Vec<usize>, Vec<String>, usize)> = (0..chunks)
        .into_par_iter()
        .map(|chunk| {
            let mut rng = Rng(seed ^ (chunk as u64).wrapping_mul(0xA24B_AED4_963E_E407));
            let mut mismatches = vec![0usize; methods.len()];
            let mut examples = Vec::new();
            let mut hits = 0;
            for _ in 0..n / chunks {
                let ray = make_ray(&mut rng, &tracer, asset);
                let (want, _) = tracer.trace(&ray, Method::BruteForce).unwrap();
                hits += want.is_some() as usize;
                for (i, &m) in methods.iter().enumerate() {
                    let (got, _) = tracer.trace(&ray, m).unwrap();
                    if !same_hit(&tracer, &ray, &got, &want) {
                        mismatches[i] += 1;
                        if examples.len() < 5 {
                            examples.push(format!(
                                "{}: {ray:?}\n   got {got:?}\n  want {want:?}",
                                m.name()
                            ));
                        }
                    }
                }
            }
            (mismatches, examples, hits)
        })
        .collect();
    let mut total = vec![0usize; methods.len()];
    let mut examples = Vec::new();
    let mut hits = 0;
    for (m, e, h) in results {
        for (t, x) in total.iter_mut().zip(m) {
            *t += x;
        }
        examples.extend(e);
        hits += h;
    }
    let rays = n / chunks * chunks;
    eprintln!(
        "{name}: {rays} rays per method, {hits} hits; mismatches {:?}",
        methods
            .iter()
            .map(|m| m.name())
            .zip(&total)
            .collect::<Vec<_>>()
    );
    // A matrix where nothing hits, or everything does, would prove little.
    assert!(
        hits > rays / 20 && hits < rays,
        "{name}: {hits} of {rays} rays hit"
    );
    assert!(
        total.iter().all(|&t| t == 0),
        "{name}: mismatches {total:?}\n{}",
        examples.join("\n")
    );
}

#[test]
fn every_method_equals_brute_force_on_every_synthetic_terrain() {
    let n = rays_per_terrain();
    for (i, kind) in SynthKind::ALL.into_iter().enumerate() {
        let dir = tempfile::tempdir().unwrap();
        // Odd, non-square, several tiles and pyramid levels.
        let asset = synth_asset(dir.path(), kind, 71, 53, i);
        check_terrain(
            &format!("{kind:?} (cones {:?})", cones_stage(i).slices),
            &asset,
            n,
            1000 + i as u64,
        );
    }
}

#[test]
fn every_method_equals_brute_force_on_the_real_dem() {
    // A 96 x 80 crop of the bundled SRTM tile, with its own cell size.
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (96u32, 80u32);
    let (crop, dx, dy) = common::srtm_crop((500, 300), (w, h));
    let raw = dir.path().join("crop.f32");
    std::fs::write(
        &raw,
        crop.iter()
            .flat_map(|z| z.to_le_bytes())
            .collect::<Vec<u8>>(),
    )
    .unwrap();
    let spec = RawSpec {
        width: w,
        height: h,
        sample: RawSampleType::F32,
        order: ByteOrder::Le,
    };
    let sub = dir.path().join("crop");
    std::fs::create_dir(&sub).unwrap();
    let asset = build_asset(&sub, &raw, Some(spec), (dx, dy), 0);
    check_terrain("SRTM crop", &asset, rays_per_terrain(), 77);
}

mod random_terrains {
    //! Property test: tiny random terrains (random heights, random nodata
    //! posts, random tile size and cell size) and random rays; every method
    //! equals the brute force.
    use super::*;
    use proptest::prelude::*;

    fn terrain() -> impl Strategy<Value = (u32, u32, Vec<f32>, f64, f64)> {
        (2u32..9, 2u32..9).prop_flat_map(|(w, h)| {
            let post = prop_oneof![8 => (-20.0f32..20.0).prop_map(|z| z.round()), 1 => Just(f32::NAN), 2 => Just(5.0f32)];
            (Just(w), Just(h), proptest::collection::vec(post, (w * h) as usize), 1.0f64..50.0, 1.0f64..50.0)
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]
        #[test]
        fn methods_agree_on_random_terrains((w, h, posts, dx, dy) in terrain(), seed in any::<u64>()) {
            let dir = tempfile::tempdir().unwrap();
            let raw = dir.path().join("t.f32");
            std::fs::write(&raw, posts.iter().flat_map(|z| z.to_le_bytes()).collect::<Vec<u8>>()).unwrap();
            let spec = RawSpec { width: w, height: h, sample: RawSampleType::F32, order: ByteOrder::Le };
            let out = dir.path().join("t.tbake");
            ingest(&raw, &out, &IngestOptions { tile_size: 16, cell_size: Some((dx, dy)), ..IngestOptions::for_raw(spec) }, Progress::hidden()).unwrap();
            run_stage(&out, &PyramidStage, false, Progress::hidden()).unwrap();
            run_stage(&out, &cones_stage(seed as usize % 15), false, Progress::hidden()).unwrap();
            let asset = Asset::open(&out).unwrap();
            let tracer = Tracer::new(&asset).unwrap();
            let mut rng = Rng(seed);
            let (xm, ym) = tracer.extent();
            for _ in 0..200 {
                // Origins snapped to a quarter of a cell half the time: rays
                // through posts, edges and corners are the hard ones.
                let mut o = [rng.range(-0.5 * xm, 1.5 * xm), rng.range(-0.5 * ym, 1.5 * ym), rng.range(-30.0, 40.0)];
                let mut d = [rng.range(-1.0, 1.0) * dx, rng.range(-1.0, 1.0) * dy, rng.range(-1.0, 1.0) * 10.0];
                if rng.int(2) == 0 {
                    o[0] = (o[0] / dx * 4.0).round() / 4.0 * dx;
                    o[1] = (o[1] / dy * 4.0).round() / 4.0 * dy;
                    d[0] = (d[0] / dx * 2.0).round() / 2.0 * dx;
                    d[1] = (d[1] / dy * 2.0).round() / 2.0 * dy;
                }
                if d == [0.0; 3] {
                    continue;
                }
                let ray = Ray { origin: o, dir: d, t_min: 0.0, t_max: f64::INFINITY };
                let (want, _) = tracer.trace(&ray, Method::BruteForce).unwrap();
                let mut cost = Vec::new();
                for m in [Method::Incremental, Method::Runs, Method::Hierarchical, Method::Parametric] {
                    let (got, c) = tracer.trace(&ray, m).unwrap();
                    prop_assert!(same_hit(&tracer, &ray, &got, &want), "{}: {ray:?}\n got {got:?}\nwant {want:?}", m.name());
                    cost.push(c);
                }
                // Leaps only skip cells: the parametric walk takes no more
                // steps than the incremental one, but for the cell each
                // leap lands in, which the walk may have entered before.
                let (inc, par) = (cost[0], cost[3]);
                prop_assert!(
                    par.steps <= inc.steps + par.leaps,
                    "{ray:?}: parametric {} steps ({} leaps) against incremental {}",
                    par.steps, par.leaps, inc.steps
                );
                // And it tests the surface of no more cells: a cell whose
                // cone's apex the ray passes above is stepped over untested.
                prop_assert!(
                    par.cells <= par.steps && par.cells <= inc.cells + par.leaps,
                    "{ray:?}: parametric tested {} cells in {} steps ({} leaps), incremental {}",
                    par.cells, par.steps, par.leaps, inc.cells
                );
            }
        }
    }
}
