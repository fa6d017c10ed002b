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

/// The second frozen asset: quantised layers (u16 cone planes with a
/// quantisation, u8 horizon angles with a nodata code), band azimuths that
/// are not multiples of 360 / S, sky layers and a nodata DEM on a geographic
/// grid. Both decoders (the generic `read_rows_f32` and the renderers'
/// `HorizonMap` / `ConePlanes`) must read the same values, and the angles
/// must be the exact sight-line horizons within the u8 encoding's error.
#[test]
fn quantised_fixture_reads_forever() {
    use terrabake::algorithms::horizon::{band_horizons, plan_bands, BandOptions, Method};
    use terrabake::stages::horizons::HorizonsStage;
    use terrabake::terrain::{RowScale, Terrain};
    use terrabake_format::cones::ConePlanes;
    use terrabake_format::horizons::HorizonMap;
    use terrabake_format::ElemType;

    let asset = Asset::open(fixture("compat_v1_quantised.tbake")).expect("asset must open");
    assert!(asset.verify().problems.is_empty());
    let m = asset.manifest();
    let (w, h) = (m.width as usize, m.height as usize);
    let z = heights(&asset);

    let horizon = asset.layer("horizon", 0).unwrap();
    let q = horizon
        .entry()
        .quantization
        .expect("u8 angles are quantised");
    assert_eq!((horizon.entry().elem, q.nodata), (ElemType::U8, Some(0)));
    let azimuths = &horizon.entry().band_azimuths;
    assert_eq!(azimuths.len(), 8);
    assert!(azimuths.windows(2).all(|p| p[0] < p[1]));
    // The exact angles, recomputed from the stored heights with the
    // recorded parameters.
    let stage = HorizonsStage::recorded(&asset).expect("horizons record");
    let bands = plan_bands(Method::Line, 8, m.cell_size.dx, m.cell_size.dy, None);
    let row_scale = terrabake::terrain::geo::row_scale(m.georef.as_ref(), h as u32);
    let terrain = Terrain::new(&z, w, h, m.cell_size.dx, m.cell_size.dy)
        .with_row_scale(RowScale::new(&row_scale))
        .with_curvature(stage.sight.curvature_coefficient(asset.manifest()));
    let map = HorizonMap::open(&asset).unwrap();
    let mut decoded = vec![0f32; w * h];
    // The fixture was baked before the sweep met posts that only a corner
    // ties to the surface (a line grazing them between two holes): there
    // its angles are lower than the exact ones, never higher, because a
    // missed vertex can only lower a horizon.
    let (mut grazed, mut compared) = (0usize, 0usize);
    for (b, band) in bands.iter().enumerate() {
        assert_eq!(band.azimuth, azimuths[b]);
        let (exact, _) = band_horizons(&terrain, band, BandOptions::default());
        horizon.read_rows_f32(b as u32, 0, &mut decoded).unwrap();
        for (i, (&got, &want)) in decoded.iter().zip(&exact).enumerate() {
            let (x, y) = ((i % w) as u32, (i / w) as u32);
            let by_map = map.angle(x, y, b as u32).unwrap();
            assert_eq!(by_map.map(|a| a as f32), (!got.is_nan()).then_some(got));
            if want.is_nan() {
                assert!(got.is_nan(), "({x}, {y}) band {b}");
            } else {
                compared += 1;
                if (got - want).abs() > 0.355 {
                    assert!(got < want, "({x}, {y}) band {b}: {got} vs {want}");
                    grazed += 1;
                }
            }
        }
    }

    assert!(
        grazed * 100 < compared,
        "{grazed} of {compared} angles differ"
    );
    eprintln!("{grazed} of {compared} angles below the exact ones (grazed posts)");

    let planes = ConePlanes::open(&asset).unwrap().expect("cone planes");
    let apex = asset.layer("cone_apex", 0).unwrap();
    assert_eq!(apex.entry().elem, ElemType::U16);
    assert!(apex.entry().quantization.is_some());
    let (cw, ch) = (apex.width() as usize, apex.height() as usize);
    let mut apexes = vec![0f32; cw * ch];
    let mut slopes = vec![0f32; cw * ch];
    apex.read_rows_f32(0, 0, &mut apexes).unwrap();
    asset
        .layer("cone_slope", 0)
        .unwrap()
        .read_rows_f32(0, 0, &mut slopes)
        .unwrap();
    for i in 0..cw * ch {
        let cone = planes.cone((i % cw) as u32, (i / cw) as u32).unwrap();
        assert_eq!(
            (apexes[i], slopes[i]),
            (cone.apex as f32, cone.slope as f32)
        );
    }

    let svf = asset.layer("svf", 0).unwrap();
    let mut values = vec![0f32; w * h];
    svf.read_rows_f32(0, 0, &mut values).unwrap();
    for (v, z) in values.iter().zip(&z) {
        assert_eq!(v.is_nan(), z.is_nan());
        assert!(v.is_nan() || (0.0..=1.0).contains(v));
    }
}
