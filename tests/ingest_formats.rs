//! Ingest of the non-TIFF sources (.hgt, raw, PNG, EXR) against the values
//! written, and bad inputs refused with a clear error and nothing left behind.

mod common;

use std::path::Path;

use common::*;
use terrabake::io::source::{ByteOrder, RawSampleType, RawSpec};
use terrabake::plumbing::progress::Progress;
use terrabake::stages::ingest::{ingest, IngestOptions};
use terrabake_format::manifest::{CrsKind, RasterType};
use terrabake_format::Asset;

fn formula(x: u32, y: u32) -> i32 {
    (x as i32 * 37 - y as i32 * 101) % 3000
}

fn ingest_ok(
    src: &Path,
    opts: &IngestOptions,
) -> (tempfile::TempDir, Asset<terrabake_format::Mmap>) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("a.tbake");
    ingest(src, &out, opts, Progress::hidden())
        .unwrap_or_else(|e| panic!("{}: {e:#}", src.display()));
    let asset = Asset::open(&out).unwrap();
    (dir, asset)
}

#[test]
fn srtm_hgt_with_voids_and_georeferencing_from_the_name() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("S12E034.hgt");
    let n = 121u32;
    let mut bytes = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let v: i16 = if x == 5 && y == 7 {
                -32768
            } else {
                formula(x, y) as i16
            };
            bytes.extend_from_slice(&v.to_be_bytes());
        }
    }
    std::fs::write(&src, bytes).unwrap();
    let (_d, asset) = ingest_ok(
        &src,
        &IngestOptions {
            tile_size: 32,
            ..Default::default()
        },
    );
    let m = asset.manifest();
    assert_eq!((m.width, m.height, m.nodata.count), (n, n, 1));
    let got = heights(&asset);
    for y in 0..n {
        for x in 0..n {
            let have = got[(y * n + x) as usize];
            if x == 5 && y == 7 {
                assert!(have.is_nan());
            } else {
                assert_eq!(have, formula(x, y) as f32, "({x}, {y})");
            }
        }
    }
    let g = m.georef.as_ref().unwrap();
    assert_eq!(
        (g.crs_kind, g.epsg, g.raster_type),
        (CrsKind::Geographic, Some(4326), RasterType::Point)
    );
    // The south-west post is exactly 12 S, 34 E; the north-east 11 S, 35 E.
    assert_eq!(g.post_to_world(0.0, f64::from(n - 1)), (34.0, -12.0));
    let (lon, lat) = g.post_to_world(f64::from(n - 1), 0.0);
    assert!((lon - 35.0).abs() < 1e-12 && (lat + 11.0).abs() < 1e-12);
}

#[test]
fn raw_rasters_in_every_type_and_byte_order() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (33u32, 20u32);
    for sample in [RawSampleType::I16, RawSampleType::U16, RawSampleType::F32] {
        for order in [ByteOrder::Le, ByteOrder::Be] {
            let mut bytes = Vec::new();
            for y in 0..h {
                for x in 0..w {
                    let v = formula(x, y).abs();
                    let b: Vec<u8> = match (sample, order) {
                        (RawSampleType::I16, ByteOrder::Le) => (-v as i16).to_le_bytes().to_vec(),
                        (RawSampleType::I16, ByteOrder::Be) => (-v as i16).to_be_bytes().to_vec(),
                        (RawSampleType::U16, ByteOrder::Le) => (v as u16).to_le_bytes().to_vec(),
                        (RawSampleType::U16, ByteOrder::Be) => (v as u16).to_be_bytes().to_vec(),
                        (RawSampleType::F32, ByteOrder::Le) => {
                            (v as f32 + 0.5).to_le_bytes().to_vec()
                        }
                        (RawSampleType::F32, ByteOrder::Be) => {
                            (v as f32 + 0.5).to_be_bytes().to_vec()
                        }
                    };
                    bytes.extend(b);
                }
            }
            let src = dir.path().join(format!("dem_{sample:?}_{order:?}.raw"));
            std::fs::write(&src, &bytes).unwrap();
            let spec = RawSpec {
                width: w,
                height: h,
                sample,
                order,
            };
            let opts = IngestOptions {
                tile_size: 16,
                cell_size: Some((2.0, 3.0)),
                ..IngestOptions::for_raw(spec)
            };
            let (_d, asset) = ingest_ok(&src, &opts);
            let got = heights(&asset);
            for y in 0..h {
                for x in 0..w {
                    let v = formula(x, y).abs() as f32;
                    let want = match sample {
                        RawSampleType::I16 => -v,
                        RawSampleType::U16 => v,
                        RawSampleType::F32 => v + 0.5,
                    };
                    assert_eq!(
                        got[(y * w + x) as usize],
                        want,
                        "{sample:?} {order:?} ({x}, {y})"
                    );
                }
            }
            assert_eq!(
                (asset.manifest().cell_size.dx, asset.manifest().cell_size.dy),
                (2.0, 3.0)
            );
        }
    }
}

#[test]
fn png_heightmap_with_scale_and_offset() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("height.png");
    let (w, h) = (50u32, 40u32);
    let mut data = Vec::new();
    for y in 0..h {
        for x in 0..w {
            data.extend_from_slice(&((x * 1000 + y * 7) as u16).to_be_bytes());
        }
    }
    let file = std::fs::File::create(&src).unwrap();
    let mut enc = png::Encoder::new(file, w, h);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    enc.write_header().unwrap().write_image_data(&data).unwrap();
    let opts = IngestOptions {
        tile_size: 16,
        z_scale: 0.5,
        z_offset: -100.0,
        ..Default::default()
    };
    let (_d, asset) = ingest_ok(&src, &opts);
    let got = heights(&asset);
    for y in 0..h {
        for x in 0..w {
            assert_eq!(
                got[(y * w + x) as usize],
                (x * 1000 + y * 7) as f32 * 0.5 - 100.0
            );
        }
    }
    assert_eq!(asset.manifest().vertical.scale, 0.5);
}

#[test]
fn openexr_single_channel_float() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("height.exr");
    let (w, h) = (37usize, 29usize);
    let values: Vec<f32> = (0..w * h)
        .map(|i| {
            if i == 100 {
                f32::NAN
            } else {
                i as f32 * 0.25 - 40.0
            }
        })
        .collect();
    let channel = AnyChannel::new("Y", FlatSamples::F32(values.clone()));
    let image = Image::from_channels((w, h), AnyChannels::sort(SmallVec::from_vec(vec![channel])));
    image.write().to_file(&src).unwrap();
    let (_d, asset) = ingest_ok(
        &src,
        &IngestOptions {
            tile_size: 16,
            ..Default::default()
        },
    );
    let got = heights(&asset);
    for (i, (&g, &v)) in got.iter().zip(&values).enumerate() {
        assert!(same_heights(g, v), "{i}: {g} {v}");
    }
    assert_eq!(asset.manifest().nodata.count, 1);
}

/// Ingest of `src` fails with a message containing `needle`, and leaves no
/// asset directory behind.
fn refused(src: &Path, opts: &IngestOptions, needle: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.tbake");
    let err = ingest(src, &out, opts, Progress::hidden()).expect_err("bad input accepted");
    let text = format!("{err:#}");
    assert!(text.contains(needle), "{text}");
    assert!(
        text.contains(&src.display().to_string()),
        "error does not name the file: {text}"
    );
    assert!(!out.exists(), "a half-made asset was left behind");
}

#[test]
fn bad_inputs_are_refused_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let text = dir.path().join("notes.tif");
    std::fs::write(&text, "this is not a tiff at all").unwrap();
    refused(&text, &IngestOptions::default(), "not a TIFF");

    let empty = dir.path().join("empty.raw");
    std::fs::write(&empty, b"").unwrap();
    let raw = |w, h| {
        IngestOptions::for_raw(RawSpec {
            width: w,
            height: h,
            sample: RawSampleType::F32,
            order: ByteOrder::Le,
        })
    };
    refused(&empty, &raw(0, 10), "empty raster");
    refused(
        &empty,
        &raw(u32::MAX, u32::MAX),
        "larger than terrabake supports",
    );
    refused(&empty, &raw(10, 10), "need 400");
    refused(
        &empty,
        &IngestOptions::default(),
        "raw heights need --raw-shape",
    );

    // An RGB TIFF is not a DEM.
    let rgb = dir.path().join("photo.tif");
    {
        let file = std::fs::File::create(&rgb).unwrap();
        let mut enc = tiff::encoder::TiffEncoder::new(file).unwrap();
        enc.write_image::<tiff::encoder::colortype::RGB8>(4, 4, &[7u8; 48])
            .unwrap();
    }
    refused(&rgb, &IngestOptions::default(), "single-band");

    let missing = dir.path().join("missing.tif");
    refused(&missing, &IngestOptions::default(), "cannot read");

    // A truncated TIFF: the header promises strips that are not there.
    let good = std::fs::read(fixture("tiff/float32_strip_none.tif")).unwrap();
    let cut = dir.path().join("cut.tif");
    std::fs::write(&cut, &good[..good.len() / 3]).unwrap();
    refused(&cut, &IngestOptions::default(), "cut.tif");

    let png_rgb = dir.path().join("rgb.png");
    {
        let mut enc = png::Encoder::new(std::fs::File::create(&png_rgb).unwrap(), 2, 2);
        enc.set_color(png::ColorType::Rgb);
        enc.write_header()
            .unwrap()
            .write_image_data(&[0u8; 12])
            .unwrap();
    }
    refused(&png_rgb, &IngestOptions::default(), "grayscale");

    // A bad option is refused before anything is written.
    let out = dir.path().join("never.tbake");
    let err = ingest(
        &fixture("tiff/int16_strip_none.tif"),
        &out,
        &IngestOptions {
            tile_size: 100,
            ..Default::default()
        },
        Progress::hidden(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("power of two"), "{err}");
    assert!(!out.exists());
}

#[test]
fn unsupported_sample_format_is_named() {
    // 64-bit integers: a TIFF the tiff crate writes, but no DEM type we take.
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("i64.tif");
    {
        let file = std::fs::File::create(&src).unwrap();
        let mut enc = tiff::encoder::TiffEncoder::new(file).unwrap();
        enc.write_image::<tiff::encoder::colortype::GrayI64>(3, 3, &[1i64; 9])
            .unwrap();
    }
    refused(&src, &IngestOptions::default(), "unsupported sample format");
}

#[test]
fn a_failed_ingest_leaves_the_existing_asset_intact() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("keep.tbake");
    let src = fixture("tiff/float32_strip_none.tif");
    ingest(
        &src,
        &out,
        &IngestOptions {
            tile_size: 16,
            ..Default::default()
        },
        Progress::hidden(),
    )
    .unwrap();
    let before = heights(&Asset::open(&out).unwrap());
    let files_before: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();

    let good = std::fs::read(&src).unwrap();
    let cut = dir.path().join("cut.tif");
    std::fs::write(&cut, &good[..good.len() - 500]).unwrap();
    assert!(ingest(&cut, &out, &IngestOptions::default(), Progress::hidden()).is_err());

    let asset = Asset::open(&out).unwrap();
    assert!(asset.verify().problems.is_empty());
    assert_eq!(
        heights(&asset)
            .iter()
            .map(|z| z.to_bits())
            .collect::<Vec<_>>(),
        before.iter().map(|z| z.to_bits()).collect::<Vec<_>>()
    );
    let files_after: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(files_before, files_after, "temporary files left behind");

    // And a stranger's non-empty directory is never written into.
    let foreign = dir.path().join("photos");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("cat.jpg"), b"meow").unwrap();
    let err = ingest(
        &src,
        &foreign,
        &IngestOptions::default(),
        Progress::hidden(),
    )
    .unwrap_err();
    assert!(format!("{err:#}").contains("refusing"), "{err:#}");
}
