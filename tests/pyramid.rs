//! The pyramid against a brute-force max and min over the cells each node
//! covers, computed from the posts, on terrains with nodata holes and odd
//! sizes (so that levels end in odd rows and columns).

mod common;

use terrabake::io::synth::SynthKind;
use terrabake::stages::ingest::IngestOptions;
use terrabake_format::trace::{PYRAMID_MAX, PYRAMID_MIN};
use terrabake_format::Asset;

#[test]
fn every_node_bounds_exactly_the_cells_below_it() {
    for (kind, w, h) in [
        (SynthKind::Holes, 131, 67),
        (SynthKind::Fractal, 40, 97),
        (SynthKind::Spike, 17, 17),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let out = common::synth_with_pyramid(
            dir.path(),
            kind,
            w,
            h,
            5,
            IngestOptions {
                tile_size: 16,
                ..Default::default()
            },
        );
        let asset = Asset::open(&out).unwrap();
        let heights = common::heights(&asset);
        let post = |c: u32, r: u32| heights[(r * w + c) as usize];
        // Per cell, from the definition: a nodata corner means no surface.
        let cell = |c: u32, r: u32| {
            let z = [
                post(c, r),
                post(c + 1, r),
                post(c, r + 1),
                post(c + 1, r + 1),
            ];
            if z.iter().any(|v| v.is_nan()) {
                (f32::NEG_INFINITY, f32::INFINITY)
            } else {
                (
                    z.iter().cloned().fold(f32::MIN, f32::max),
                    z.iter().cloned().fold(f32::MAX, f32::min),
                )
            }
        };
        let mut level = 0u32;
        while let Ok(max_layer) = asset.layer(PYRAMID_MAX, level) {
            let min_layer = asset.layer(PYRAMID_MIN, level).unwrap();
            let s = 1u32 << level;
            assert_eq!(max_layer.width(), (w - 1).div_ceil(s));
            assert_eq!(max_layer.height(), (h - 1).div_ceil(s));
            for b in 0..max_layer.height() {
                for a in 0..max_layer.width() {
                    let (mut hi, mut lo) = (f32::NEG_INFINITY, f32::INFINITY);
                    for r in b * s..((b + 1) * s).min(h - 1) {
                        for c in a * s..((a + 1) * s).min(w - 1) {
                            let (x, n) = cell(c, r);
                            hi = hi.max(x);
                            lo = lo.min(n);
                        }
                    }
                    assert_eq!(
                        max_layer.get::<f32>(0, a, b).unwrap(),
                        hi,
                        "{kind:?} level {level} ({a}, {b})"
                    );
                    assert_eq!(
                        min_layer.get::<f32>(0, a, b).unwrap(),
                        lo,
                        "{kind:?} level {level} ({a}, {b})"
                    );
                }
            }
            level += 1;
        }
        let top = asset.layer(PYRAMID_MAX, level - 1).unwrap();
        assert!(
            top.width() <= 16 && top.height() <= 16,
            "{kind:?}: the top level fits one tile"
        );
        assert!(level >= 2 || w <= 17, "{kind:?}: {level} levels");
    }
}
