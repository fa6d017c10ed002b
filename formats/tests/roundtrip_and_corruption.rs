//! The writer and reader agree, and no corruption of any file makes the
//! reader panic or read out of bounds: it returns an error naming the file,
//! the layer and, where it applies, the tile.

use std::collections::HashMap;
use std::path::Path;

mod common;

use proptest::prelude::*;
use terrabake_format::layout::HEADER_LEN;
use terrabake_format::manifest::*;
use terrabake_format::*;
use zerocopy::IntoBytes;

const W: u32 = 100;
const H: u32 = 70;
const TS: u32 = 32;

fn value(x: u32, y: u32) -> f32 {
    // Nodata in the top-right tiles, flat in the top-left tile.
    if x >= 64 && y < 32 {
        f32::NAN
    } else if x < 32 && y < 32 {
        5.0
    } else {
        (x * 3 + y * 1000) as f32 * 0.25
    }
}

fn lock(dir: &Path) -> WriteLock {
    WriteLock::acquire(dir, true, |_| {}).unwrap()
}

fn manifest(layers: Vec<LayerEntry>) -> Manifest {
    let values: Vec<f32> = (0..H)
        .flat_map(|y| (0..W).map(move |x| value(x, y)))
        .collect();
    let valid = values.iter().filter(|z| !z.is_nan());
    let (min, max) = valid.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &z| {
        (a.min(z), b.max(z))
    });
    common::manifest(
        (W, H, TS),
        (2.0, 3.0),
        layers,
        values.iter().filter(|z| z.is_nan()).count() as u64,
        Some(HeightRange { min, max }),
    )
}

fn write_layer(dir: &Path, name: &str, codec: Codec) -> LayerEntry {
    let spec = LayerSpec {
        name: name.into(),
        level: 0,
        elem: ElemType::F32,
        bands: 2,
        width: W,
        height: H,
        tile_size: TS,
        codec,
        fill_bits: u64::from(f32::NAN.to_bits()),
        stage: "test".into(),
        description: String::new(),
    };
    let mut w = LayerWriter::create(dir, spec.clone()).unwrap();
    for band in 0..2u32 {
        for ty in 0..spec.tiles_y() {
            for tx in 0..spec.tiles_x() {
                let mut tile = vec![f32::NAN; (TS * TS) as usize];
                for y in 0..TS {
                    for x in 0..TS {
                        let (gx, gy) = (tx * TS + x, ty * TS + y);
                        if gx < W && gy < H {
                            tile[(y * TS + x) as usize] = value(gx, gy) + band as f32 * 1e6;
                        }
                    }
                }
                w.push(encode_tile(tile.as_bytes(), 4, codec, 3)).unwrap();
            }
        }
    }
    w.finish().unwrap()
}

/// An asset with a raw and a zstd layer, written to disk and read back as bytes.
fn asset_files() -> (tempfile::TempDir, HashMap<String, Vec<u8>>) {
    let dir = tempfile::tempdir().unwrap();
    let raw = write_layer(dir.path(), "height", Codec::Raw);
    let zstd = write_layer(dir.path(), "packed", Codec::Zstd);
    commit_manifest(&lock(dir.path()), &manifest(vec![raw, zstd])).unwrap();
    let files = std::fs::read_dir(dir.path())
        .unwrap()
        .filter(|e| e.as_ref().unwrap().file_name() != LOCK_FILE)
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().into_string().unwrap(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    (dir, files)
}

fn check_values<D: AsRef<[u8]>>(asset: &Asset<D>) {
    for name in ["height", "packed"] {
        let layer = asset.layer(name, 0).unwrap();
        for band in 0..2u32 {
            for y in 0..H {
                for x in 0..W {
                    let got: f32 = layer.get(band, x, y).unwrap();
                    let want = value(x, y) + band as f32 * 1e6;
                    assert!(
                        got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                        "{name} band {band} ({x},{y}): {got} != {want}"
                    );
                }
            }
        }
    }
}

#[test]
fn mmap_and_memory_readers_agree_with_the_writer() {
    let (dir, files) = asset_files();
    let mapped = Asset::open(dir.path()).unwrap();
    check_values(&mapped);
    let in_memory = Asset::from_files(dir.path(), files).unwrap();
    check_values(&in_memory);
    let report = mapped.verify();
    assert!(report.problems.is_empty(), "{:?}", report.problems);
    assert_eq!(report.chunks, 2 * 2 * 4 * 3);
}

#[test]
fn raw_tiles_are_borrowed_in_place_and_zstd_tiles_cached() {
    let (dir, _) = asset_files();
    let asset = Asset::open(dir.path()).unwrap();
    let raw = asset
        .layer("height", 0)
        .unwrap()
        .tile::<f32>(0, 1, 1)
        .unwrap();
    assert!(matches!(raw, Tile::Borrowed(_)));
    let packed = asset
        .layer("packed", 0)
        .unwrap()
        .tile::<f32>(0, 1, 1)
        .unwrap();
    assert!(matches!(packed, Tile::Cached(..)));
    assert_eq!(&*raw, &*packed);
    // Wrong element type is an error, not a reinterpretation.
    let err = asset
        .layer("height", 0)
        .unwrap()
        .tile::<u16>(0, 0, 0)
        .unwrap_err();
    assert!(err.to_string().contains("f32"), "{err}");
}

/// Asked for zstd, each tile keeps the smallest of raw, plain zstd and
/// shuffled zstd, and every one of them reads back bit for bit.
#[test]
fn zstd_keeps_the_smallest_of_plain_and_shuffled_per_tile() {
    let n = (TS * TS) as usize;
    let smooth: Vec<f32> = (0..n)
        .map(|i| 1000.0 + (i as f32 * 0.37).sin() * 40.0)
        .collect();
    // Few distinct values in a repeating run: plain zstd finds the period.
    let steps: Vec<f32> = (0..n).map(|i| ((i / 3) % 4) as f32 * 1.5e-3).collect();
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let noise: Vec<f32> = (0..n)
        .map(|_| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            f32::from_bits(seed as u32)
        })
        .collect();
    for (tile, want) in [
        (&smooth, Codec::ShuffledZstd),
        (&steps, Codec::Zstd),
        (&noise, Codec::Raw),
    ] {
        let raw = tile.as_bytes();
        let encoded = encode_tile(raw, 4, Codec::Zstd, 3);
        assert_eq!(encoded.codec, want);
        let plain = zstd::bulk::compress(raw, 3).unwrap().len();
        let shuffled = zstd::bulk::compress(&layout::shuffle(raw, 4), 3)
            .unwrap()
            .len();
        assert_eq!(encoded.bytes.len(), plain.min(shuffled).min(raw.len()));
        let mut back = vec![0u8; raw.len()];
        let len = encoded
            .codec
            .decode_into(&encoded.bytes, 4, &mut back)
            .unwrap();
        assert_eq!((len, &back[..]), (raw.len(), raw));
    }
    // One-byte elements have nothing to shuffle.
    let codes: Vec<u8> = (0..n).map(|i| (i / 7 % 200) as u8).collect();
    assert_eq!(encode_tile(&codes, 1, Codec::Zstd, 3).codec, Codec::Zstd);
    // The asset's zstd layer holds both kinds of chunk, and check_values
    // (above) reads each back.
    let (dir, _) = asset_files();
    let asset = Asset::open(dir.path()).unwrap();
    let packed = asset.layer("packed", 0).unwrap();
    let codecs: std::collections::HashSet<Codec> = (0..24)
        .map(|c| packed.stored_chunk(c).unwrap().codec)
        .collect();
    assert!(codecs.contains(&Codec::ShuffledZstd), "{codecs:?}");
    assert!(packed.verify().is_empty());
}

#[test]
fn constant_tiles_are_stored_once() {
    let (_dir, files) = asset_files();
    let asset = Asset::from_files("mem", files).unwrap();
    let entry = asset.layer("height", 0).unwrap().entry();
    // Per band: two NaN tiles (one of them NaN only through its padding)
    // and one flat tile (5 m in band 0, 1e6 + 5 m in band 1).
    assert_eq!(entry.constant_chunks, 6);
    let tile_bytes = u64::from(TS * TS * 4);
    // 24 chunks; the six constant ones take three stored copies (NaN, 5, 1e6 + 5).
    assert_eq!(entry.stored_bytes, tile_bytes * (24 - 6 + 3));
}

#[test]
fn bilinear_interpolates_and_respects_nodata() {
    let (dir, _) = asset_files();
    let asset = Asset::open(dir.path()).unwrap();
    let l = asset.layer("height", 0).unwrap();
    // Across a tile border (x 31.5 -> posts 31 and 32).
    let z = l.bilinear(31.5, 10.25).unwrap().unwrap();
    let want =
        0.5 * (value(31, 10) + value(32, 10)) * 0.75 + 0.5 * (value(31, 11) + value(32, 11)) * 0.25;
    assert!((z - want).abs() < 1e-3, "{z} {want}");
    assert_eq!(l.bilinear(70.0, 5.0).unwrap(), None, "nodata post");
    assert_eq!(l.bilinear(-0.5, 5.0).unwrap(), None, "outside");
    assert_eq!(
        l.bilinear(99.0, 69.0).unwrap(),
        Some(value(99, 69)),
        "last post"
    );
}

#[test]
fn truncated_files_are_refused() {
    let (_dir, files) = asset_files();
    for (name, bytes) in &files {
        for cut in [0, 1, 31, HEADER_LEN, bytes.len() / 2, bytes.len() - 1] {
            let mut f = files.clone();
            f.insert(name.clone(), bytes[..cut.min(bytes.len())].to_vec());
            let err = Asset::from_files("mem", f).expect_err("truncated file accepted");
            assert!(err.to_string().contains(name.as_str()), "{name}: {err}");
        }
    }
}

#[test]
fn wrong_version_says_which() {
    let (_dir, files) = asset_files();
    for name in [
        MANIFEST_FILE.to_string(),
        files.keys().find(|k| k.ends_with(".tbl")).unwrap().clone(),
    ] {
        let mut f = files.clone();
        f.get_mut(&name).unwrap()[8] = 2;
        match Asset::from_files("mem", f) {
            Err(Error::Version {
                expected: 1,
                got: 2,
                ..
            }) => {}
            other => panic!("{name}: {other:?}"),
        }
    }
}

#[test]
fn flipped_bits_are_found() {
    let (_dir, files) = asset_files();
    let layer_file = files
        .keys()
        .find(|k| k.starts_with("height"))
        .unwrap()
        .clone();
    let len = files[&layer_file].len();
    // In the manifest JSON.
    let mut f = files.clone();
    let m = f.get_mut(MANIFEST_FILE).unwrap();
    let at = m.len() - 20;
    m[at] ^= 0x04;
    let err = Asset::from_files("mem", f).unwrap_err();
    assert!(
        matches!(
            err,
            Error::Checksum {
                what: "manifest",
                ..
            }
        ),
        "{err}"
    );
    // In the chunk index (just before the 64-byte footer).
    let mut f = files.clone();
    f.get_mut(&layer_file).unwrap()[len - 64 - 10] ^= 0x01;
    let err = Asset::from_files("mem", f).unwrap_err();
    assert!(
        matches!(
            err,
            Error::Checksum {
                what: "chunk index",
                ..
            }
        ),
        "{err}"
    );
    // In a tile: the asset opens, the tile read names the tile, verify finds it.
    let mut f = files.clone();
    f.get_mut(&layer_file).unwrap()[HEADER_LEN + 100] ^= 0x80;
    let asset = Asset::from_files("mem", f).unwrap();
    let err = asset.height().unwrap().tile::<f32>(0, 0, 0).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("height@0") && text.contains("tile (0, 0)") && text.contains(&layer_file),
        "{text}"
    );
    let report = asset.verify();
    assert_eq!(report.problems.len(), 1, "{:?}", report.problems);
    // Other tiles still read.
    assert!(asset.height().unwrap().tile::<f32>(0, 1, 0).is_ok());
}

#[test]
fn a_layer_file_from_another_version_is_refused() {
    let (dir, files) = asset_files();
    // Re-write the same layer: same name, new generation, different file.
    let again = write_layer(dir.path(), "height", Codec::Zstd);
    let old = files
        .keys()
        .find(|k| k.starts_with("height"))
        .unwrap()
        .clone();
    let mut f = files.clone();
    f.insert(
        old.clone(),
        std::fs::read(dir.path().join(&again.file)).unwrap(),
    );
    let err = Asset::from_files("mem", f).unwrap_err();
    assert!(err.to_string().contains(&old), "{err}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]
    /// Any byte of any file set to any value: the reader returns an error or
    /// a working asset, and reading every tile of it never panics.
    #[test]
    fn corruption_never_panics(file_pick in 0usize..3, pos in any::<prop::sample::Index>(), byte in any::<u8>()) {
        let (_dir, mut files) = FILES.with(|f| f.clone());
        let mut names: Vec<String> = files.keys().cloned().collect();
        names.sort();
        let name = &names[file_pick % names.len()];
        let bytes = files.get_mut(name).unwrap();
        let at = pos.index(bytes.len());
        bytes[at] = byte;
        if let Ok(asset) = Asset::from_files("mem", files) {
            for layer in asset.layers() {
                for band in 0..layer.bands() {
                    for ty in 0..layer.tiles_y() {
                        for tx in 0..layer.tiles_x() {
                            let _ = layer.tile::<f32>(band, tx, ty).map(|t| t.len());
                        }
                    }
                }
            }
            let _ = asset.verify();
        }
    }
}

thread_local! {
    static FILES: (std::sync::Arc<tempfile::TempDir>, HashMap<String, Vec<u8>>) = {
        let (d, f) = asset_files();
        (std::sync::Arc::new(d), f)
    };
}

#[test]
fn threads_share_one_asset() {
    let (dir, _) = asset_files();
    let asset = Asset::open_with_cache(dir.path(), 3 * 4096 * 4).unwrap();
    std::thread::scope(|s| {
        for t in 0..4u32 {
            let asset = &asset;
            s.spawn(move || {
                for i in 0..2000u32 {
                    let (x, y) = ((i * 7 + t * 13) % W, (i * 11 + t) % H);
                    let got: f32 = asset.layer("packed", 0).unwrap().get(1, x, y).unwrap();
                    let want = value(x, y) + 1e6;
                    assert!(got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()));
                }
            });
        }
    });
}

#[test]
fn world_coordinates_map_to_posts() {
    use terrabake_format::manifest::{CrsKind, Georef, RasterType};
    let (dir, _) = asset_files();
    let mut m = Asset::open(dir.path()).unwrap().manifest().clone();
    m.georef = Some(Georef {
        crs_kind: CrsKind::Projected,
        epsg: Some(32630),
        geotransform: [500000.0, 2.0, 0.0, 900000.0, 0.0, -3.0],
        raster_type: RasterType::Area,
        geo_key_directory: vec![],
        geo_double_params: vec![],
        geo_ascii_params: String::new(),
    });
    commit_manifest(&lock(dir.path()), &m).unwrap();
    let asset = Asset::open(dir.path()).unwrap();
    // Post (40, 50) of a PixelIsArea grid is the centre of pixel (40, 50).
    let (x, y) = (500000.0 + 40.5 * 2.0, 900000.0 - 50.5 * 3.0);
    assert_eq!(asset.height_at_world(x, y).unwrap(), Some(value(40, 50)));
    let g = asset.manifest().georef.as_ref().unwrap();
    let (px, py) = g.world_to_post(x + 1.0, y - 1.5).unwrap();
    assert!((px - 40.5).abs() < 1e-9 && (py - 50.5).abs() < 1e-9);
    assert_eq!(asset.height_at_world(0.0, 0.0).unwrap(), None);
}
