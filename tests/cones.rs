//! The cone planes against their definition, by brute force on small DEMs:
//! every cell's stored cone (after encoding) must hold no terrain, on every
//! synthetic terrain, for slice counts from 1 to far more than the data's
//! height steps, for exact cones, for every encoding and for windowed
//! (out-of-core) bakes; exact cones must be the widest possible.
//!
//! The reference works on the surface itself: cell `C'` reaches up to its
//! tallest corner (no surface where a corner is nodata), and the distance is
//! between the closed squares of the two cells. It shares nothing with the
//! stage's algorithm (neighbourhood maxima, slices, distance transforms,
//! branch and bound).

mod common;

use std::path::Path;

use terrabake::algorithms::planes::exact::brute_force_slopes;

use terrabake::algorithms::planes::neighbourhood_max;
use terrabake::io::synth::SynthKind;
use terrabake::plumbing::progress::Progress;
use terrabake::stage::run_stage;
use terrabake::stages::cones::{ConesStage, SliceChoice};
use terrabake::stages::ingest::IngestOptions;
use terrabake_format::cones::{Cone, ConeEncoding, ConePlanes};
use terrabake_format::surface::Cell;
use terrabake_format::{Asset, Mmap};

fn opts() -> IngestOptions {
    IngestOptions {
        tile_size: 16,
        cell_size: Some((30.0, 20.0)),
        ..Default::default()
    }
}

fn bake_cones(dir: &Path, stage: &ConesStage) -> Asset<Mmap> {
    let out = dir.join("t.tbake");
    run_stage(&out, stage, true, Progress::hidden()).unwrap();
    Asset::open(&out).unwrap()
}

/// Per cell: tallest corner (`-inf` without surface).
fn cell_max(asset: &Asset<Mmap>) -> (Vec<f32>, usize, usize) {
    let posts = common::heights(asset);
    let h = asset.height().unwrap();
    let (w, hh) = (h.width() as usize, h.height() as usize);
    let (cw, ch) = (w - 1, hh - 1);
    let mut out = Vec::with_capacity(cw * ch);
    for r in 0..ch {
        for c in 0..cw {
            out.push(
                Cell {
                    nw: posts[r * w + c],
                    ne: posts[r * w + c + 1],
                    sw: posts[(r + 1) * w + c],
                    se: posts[(r + 1) * w + c + 1],
                }
                .max(),
            );
        }
    }
    (out, cw, ch)
}

fn cones(asset: &Asset<Mmap>, cw: usize, ch: usize) -> Vec<Cone> {
    let planes = ConePlanes::open(asset).unwrap().expect("planes");
    (0..cw * ch)
        .map(|i| planes.cone((i % cw) as u32, (i / cw) as u32).unwrap())
        .collect()
}

/// Distance in metres between the closed squares of cells `i` and `j`.
fn square_distance(i: usize, j: usize, cw: usize, (dx, dy): (f64, f64)) -> f64 {
    let gap = |a: usize, b: usize| (a.abs_diff(b).saturating_sub(1)) as f64;
    let ex = gap(i % cw, j % cw) * dx;
    let ey = gap(i / cw, j / cw) * dy;
    ex.hypot(ey)
}

/// Cells whose cone holds terrain, with the first few for the message.
fn violations(asset: &Asset<Mmap>) -> (usize, Vec<String>) {
    let (tall, cw, ch) = cell_max(asset);
    let cones = cones(asset, cw, ch);
    let cs = &asset.manifest().cell_size;
    let mut bad = 0;
    let mut examples = Vec::new();
    for (i, cone) in cones.iter().enumerate() {
        assert!(
            cone.slope >= 0.0 && !cone.apex.is_nan(),
            "cell {i}: {cone:?}"
        );
        for (j, &z) in tall.iter().enumerate() {
            let rise = f64::from(z) - cone.apex;
            if rise > 0.0 && square_distance(i, j, cw, (cs.dx, cs.dy)) < cone.slope * rise {
                bad += 1;
                if examples.len() < 3 {
                    examples.push(format!("cell {i} {cone:?}: cell {j} at height {z}"));
                }
                break;
            }
        }
    }
    (bad, examples)
}

#[test]
fn no_cone_holds_terrain_on_any_synthetic_terrain() {
    let choices = [
        SliceChoice::Count(1),
        SliceChoice::Count(2),
        SliceChoice::Count(7),
        SliceChoice::Count(64),
        SliceChoice::Count(5000),
        SliceChoice::Auto,
        SliceChoice::Exact,
    ];
    for kind in SynthKind::ALL {
        let dir = tempfile::tempdir().unwrap();
        common::synth_with_pyramid(dir.path(), kind, 41, 33, 5, opts());
        for (n, &slices) in choices.iter().enumerate() {
            // Every encoding, in turn.
            let encoding = ConeEncoding::ALL[n % 3];
            let asset = bake_cones(
                dir.path(),
                &ConesStage {
                    slices,
                    encoding,
                    ..Default::default()
                },
            );
            let (bad, examples) = violations(&asset);
            assert_eq!(bad, 0, "{kind:?} {slices:?} {encoding:?}: {examples:?}");
        }
    }
}

#[test]
fn exact_cones_are_the_widest_for_their_apex() {
    for kind in SynthKind::ALL {
        let dir = tempfile::tempdir().unwrap();
        common::synth_with_pyramid(dir.path(), kind, 37, 29, 9, opts());
        let asset = bake_cones(
            dir.path(),
            &ConesStage {
                slices: SliceChoice::Exact,
                ..Default::default()
            },
        );
        let (tall, cw, ch) = cell_max(&asset);
        let cones = cones(&asset, cw, ch);
        let cs = &asset.manifest().cell_size;
        for (i, cone) in cones.iter().enumerate() {
            // The widest slope that the definition allows for this apex.
            let widest = tall
                .iter()
                .enumerate()
                .filter(|&(_, &z)| f64::from(z) > cone.apex)
                .map(|(j, &z)| {
                    square_distance(i, j, cw, (cs.dx, cs.dy)) / (f64::from(z) - cone.apex)
                })
                .fold(f64::INFINITY, f64::min);
            assert!(
                cone.slope <= widest && cone.slope >= widest * (1.0 - 1e-6),
                "{kind:?} cell {i}: slope {} but the widest is {widest}",
                cone.slope
            );
        }
        // The apex is the lowest possible: the tallest corner touching the cell.
        let posts = common::heights(&asset);
        let nmax = neighbourhood_max(&posts, cw + 1, ch + 1);
        for (i, cone) in cones.iter().enumerate() {
            if nmax[i].is_finite() {
                assert_eq!(cone.apex, f64::from(nmax[i]), "{kind:?} cell {i}");
            }
        }
        // The algorithm's own reference on neighbourhood maxima agrees.
        let apex: Vec<f32> = cones.iter().map(|c| c.apex as f32).collect();
        let brute = brute_force_slopes(&nmax, (cw, ch), (cs.dx, cs.dy), &apex);
        for (i, (c, b)) in cones.iter().zip(&brute).enumerate() {
            assert!(
                c.slope <= *b && c.slope >= b * (1.0 - 1e-6),
                "{kind:?} cell {i}: {} vs {b}",
                c.slope
            );
        }
    }
}

#[test]
fn flat_dems_and_one_slice_give_unbounded_cones_at_the_top() {
    let dir = tempfile::tempdir().unwrap();
    common::synth_with_pyramid(dir.path(), SynthKind::Flat, 20, 17, 1, opts());
    for slices in [
        SliceChoice::Count(1),
        SliceChoice::Count(300),
        SliceChoice::Auto,
        SliceChoice::Exact,
    ] {
        let asset = bake_cones(
            dir.path(),
            &ConesStage {
                slices,
                ..Default::default()
            },
        );
        for cone in cones(&asset, 19, 16) {
            assert_eq!(
                cone,
                Cone {
                    apex: 100.0,
                    slope: f64::INFINITY
                },
                "{slices:?}"
            );
        }
    }
    // One slice on real relief: the apex is the DEM's top, the cone unbounded.
    common::synth_with_pyramid(dir.path(), SynthKind::Sine, 20, 17, 1, opts());
    let asset = bake_cones(
        dir.path(),
        &ConesStage {
            slices: SliceChoice::Count(1),
            ..Default::default()
        },
    );
    let top = common::heights(&asset)
        .into_iter()
        .fold(f32::NEG_INFINITY, f32::max);
    for cone in cones(&asset, 19, 16) {
        assert_eq!(
            cone,
            Cone {
                apex: f64::from(top),
                slope: f64::INFINITY
            }
        );
    }
}

#[test]
fn windowed_bakes_are_valid_and_never_wider_than_whole_ones() {
    for kind in [SynthKind::Fractal, SynthKind::Spike, SynthKind::Holes] {
        let dir = tempfile::tempdir().unwrap();
        common::synth_with_pyramid(dir.path(), kind, 90, 75, 3, opts());
        for slices in [SliceChoice::Count(32), SliceChoice::Exact] {
            let whole = bake_cones(
                dir.path(),
                &ConesStage {
                    slices,
                    ..Default::default()
                },
            );
            let (cw, ch) = (89, 74);
            let whole_cones = cones(&whole, cw, ch);
            drop(whole);
            // Windows of 16-cell cores with 8-cell halos.
            let windowed = bake_cones(
                dir.path(),
                &ConesStage {
                    slices,
                    max_memory: 32 * 32 * terrabake::stages::cones::BYTES_PER_CELL,
                    ..Default::default()
                },
            );
            assert!(windowed
                .layer("cone_slope", 0)
                .unwrap()
                .entry()
                .description
                .contains("windowed"));
            let (bad, examples) = violations(&windowed);
            assert_eq!(bad, 0, "{kind:?} {slices:?}: {examples:?}");
            for (i, (w, c)) in cones(&windowed, cw, ch)
                .iter()
                .zip(&whole_cones)
                .enumerate()
            {
                assert_eq!(w.apex, c.apex, "{kind:?} {slices:?} cell {i}");
                assert!(
                    w.slope <= c.slope,
                    "{kind:?} {slices:?} cell {i}: {w:?} vs {c:?}"
                );
            }
        }
    }
}

/// The format crate's one decoder (`Layer::read_rows_f32`) gives every
/// stored plane's real values, in every encoding: the same numbers the
/// parametric tracer's `ConePlanes::cone` decodes, cell by cell.
#[test]
fn the_generic_decoder_reads_every_cone_encoding() {
    let dir = tempfile::tempdir().unwrap();
    common::synth_with_pyramid(dir.path(), SynthKind::Fractal, 37, 29, 5, opts());
    for encoding in ConeEncoding::ALL {
        let stage = ConesStage {
            slices: SliceChoice::Count(8),
            encoding,
            ..Default::default()
        };
        let asset = bake_cones(dir.path(), &stage);
        let planes = ConePlanes::open(&asset).unwrap().unwrap();
        let read = |name: &str| {
            let layer = asset.layer(name, 0).unwrap();
            let mut v = vec![0f32; (layer.width() * layer.height()) as usize];
            layer.read_rows_f32(0, 0, &mut v).unwrap();
            (v, layer.width() as usize)
        };
        let ((apex, w), (slope, _)) = (read("cone_apex"), read("cone_slope"));
        for (i, (a, s)) in apex.iter().zip(&slope).enumerate() {
            let cone = planes.cone((i % w) as u32, (i / w) as u32).unwrap();
            let same = |got: f32, want: f64| got == want as f32 || (got.is_nan() && want.is_nan());
            assert!(
                same(*a, cone.apex),
                "{encoding:?} apex {a} vs {}",
                cone.apex
            );
            assert!(
                same(*s, cone.slope),
                "{encoding:?} slope {s} vs {}",
                cone.slope
            );
        }
    }
}

/// Sliced cones are as wide as Paglieroni and Petersen's definition allows
/// (sec. 2.2), not merely safe: per cell, the apex at the first slice the
/// cell is not part of, and the slope the least over the slices at or
/// above it of `D_k / (z_k+1 - apex)`, `D_k` the distance to the nearest
/// cell of slice `k`'s bit plane (`nmax >= z_k`) and `z_K` the DEM's top.
/// Computed here by brute force over every pair of cells; a cone narrower
/// than that (a slice skipped that bounds, a far parabola left out that
/// mattered) fails, as a wider one would.
#[test]
fn sliced_cones_are_as_wide_as_the_definition_allows() {
    use terrabake::algorithms::planes::{sliced_planes, Slices};
    // Unequal spacings; rows across three shares of 64 columns, whose
    // plane cells between near neighbours are left out of the rows'
    // envelopes (`Span::hidden_bits`); and columns across three bands of
    // rows (32, 32 and 5), whose column distances meet at the bands'
    // edges, with slices past 255 (two-byte apex slices).
    type Shape = ((usize, usize), (f64, f64), &'static [usize]);
    let shapes: [Shape; 3] = [
        ((31, 23), (30.0, 20.0), &[1, 2, 5, 16, 200]),
        ((151, 9), (25.0, 25.0), &[3, 16]),
        ((9, 70), (20.0, 30.0), &[3, 16, 300]),
    ];
    for (kind, ((w, h), (dx, dy), ks)) in [SynthKind::Fractal, SynthKind::Blocks, SynthKind::Holes]
        .into_iter()
        .flat_map(|kind| shapes.map(|shape| (kind, shape)))
    {
        let mut posts = vec![0f32; w * h];
        terrabake::io::synth::fill_rows(kind, 0, &mut posts, w as u32, h as u32, 4);
        let (cw, ch) = (w - 1, h - 1);
        let nmax = neighbourhood_max(&posts, w, h);
        let finite = nmax.iter().filter(|v| v.is_finite()).map(|&v| f64::from(v));
        let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
        for &k in ks {
            let slices = Slices::uniform(lo, hi, k);
            let planes = sliced_planes(&nmax, (cw, ch), (dx, dy), &slices, None, &|| {});
            let z_at = |s: usize| slices.z.get(s).copied().unwrap_or(slices.top);
            for i in 0..cw * ch {
                let a = slices.member_of(nmax[i]);
                let apex = z_at(a);
                // The apex is stored rounded up to f32 (a safe cone).
                let stored = f64::from(planes.apex[i]);
                assert!(
                    stored >= apex && stored - apex <= apex.abs() * 1e-6,
                    "{kind:?} K={k} cell {i}: apex {stored}, slice {apex}"
                );
                let (x, y) = ((i % cw) as f64, (i / cw) as f64);
                let mut widest = f64::INFINITY;
                for s in a..k {
                    let d = (0..cw * ch)
                        .filter(|&j| slices.member_of(nmax[j]) > s)
                        .map(|j| ((x - (j % cw) as f64) * dx).hypot((y - (j / cw) as f64) * dy))
                        .fold(f64::INFINITY, f64::min);
                    widest = widest.min(d / (z_at(s + 1) - apex));
                }
                let got = f64::from(planes.slope[i]);
                assert!(
                    got <= widest && (got >= widest * (1.0 - 1e-6) || got == widest),
                    "{kind:?} K={k} cell {i}: slope {got}, the definition allows {widest}"
                );
            }
        }
    }
}
