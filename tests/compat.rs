//! The committed format-v1 asset (tests/fixtures/compat_v1.tbake) must read
//! forever: if this fails, the change broke assets already in users' hands.

mod common;

use common::*;
use terrabake_format::manifest::CrsKind;
use terrabake_format::{Asset, Codec, FORMAT_VERSION};

#[test]
fn format_v1_fixture_reads_forever() {
    let asset = Asset::open(fixture("compat_v1.tbake")).expect("v1 asset must open");
    let m = asset.manifest();
    assert_eq!(m.format_version, 1);
    assert_eq!(
        FORMAT_VERSION, 1,
        "a new version must keep reading v1: add compat_v2 beside this"
    );
    assert_eq!((m.width, m.height, m.tile_size), (FIXTURE_W, FIXTURE_H, 16));
    let g = m.georef.as_ref().unwrap();
    assert_eq!((g.crs_kind, g.epsg), (CrsKind::Projected, Some(32630)));
    assert_eq!(g.geotransform, [500000.0, 90.0, 0.0, 900000.0, 0.0, -90.0]);
    assert_eq!(m.nodata.source_value.as_deref(), Some("-9999"));
    let layer = asset.height().unwrap();
    assert_eq!(layer.entry().codec, Codec::Zstd);
    // The two sparse (all-nodata) source tiles are constant chunks sharing one copy.
    assert_eq!(layer.entry().constant_chunks, 2);
    let mut holes = 0;
    for y in 0..FIXTURE_H {
        for x in 0..FIXTURE_W {
            let hole = ((0..16).contains(&y) && (16..32).contains(&x))
                || ((32..45).contains(&y) && (48..64).contains(&x));
            match layer.height_at(x, y).unwrap() {
                None => {
                    assert!(hole, "({x}, {y})");
                    holes += 1;
                }
                Some(z) => assert_eq!(z, fixture_value("float32", x, y), "({x}, {y})"),
            }
        }
    }
    assert_eq!(m.nodata.count, holes);
    assert!(asset.verify().problems.is_empty());
}
