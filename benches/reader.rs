//! Reader costs: opening an asset, and reading tiles, posts and bilinear
//! samples from raw (mapped in place) and zstd (cached) layers.
//!
//! `cargo bench -p terrabake-bench --bench reader`; set
//! `TERRABAKE_BENCH_ASSET=path/to/asset` to also time opening that asset.

#[path = "../formats/tests/common/mod.rs"]
mod common;

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use terrabake_format::manifest::*;
use terrabake_format::*;
use zerocopy::IntoBytes;

const N: u32 = 4096;
const TS: u32 = 256;

fn write_layer(dir: &std::path::Path, name: &str, codec: Codec) -> LayerEntry {
    let spec = LayerSpec {
        name: name.into(),
        level: 0,
        elem: ElemType::F32,
        bands: 1,
        width: N,
        height: N,
        tile_size: TS,
        codec,
        fill_bits: u64::from(f32::NAN.to_bits()),
        stage: "bench".into(),
        description: String::new(),
    };
    let mut w = LayerWriter::create(dir, spec).unwrap();
    for ty in 0..N / TS {
        for tx in 0..N / TS {
            let tile: Vec<f32> = (0..TS * TS)
                .map(|i| {
                    let (x, y) = (tx * TS + i % TS, ty * TS + i / TS);
                    ((x as f32 * 0.01).sin() * 300.0 + (y as f32 * 0.013).cos() * 200.0).round()
                })
                .collect();
            w.push(encode_tile(tile.as_bytes(), 4, codec, 3)).unwrap();
        }
    }
    w.finish().unwrap()
}

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let layers = vec![
        write_layer(dir.path(), "height", Codec::Raw),
        write_layer(dir.path(), "packed", Codec::Zstd),
    ];
    let manifest = common::manifest((N, N, TS), (30.0, 30.0), layers, 0, None);
    commit_manifest(
        &WriteLock::acquire(dir.path(), true, |_| {}).unwrap(),
        &manifest,
    )
    .unwrap();

    c.bench_function("open 4096^2 asset (2 layers, 512 chunks)", |b| {
        b.iter(|| Asset::open(dir.path()).unwrap())
    });
    if let Ok(path) = std::env::var("TERRABAKE_BENCH_ASSET") {
        c.bench_function(&format!("open {path}"), |b| {
            b.iter(|| Asset::open(&path).unwrap())
        });
    }
    let asset = Asset::open(dir.path()).unwrap();
    let (raw, packed) = (
        asset.layer("height", 0).unwrap(),
        asset.layer("packed", 0).unwrap(),
    );
    let mut i = 0u32;
    c.bench_function("tile raw (borrowed from the mapping)", |b| {
        b.iter(|| {
            i = i.wrapping_add(7);
            black_box(raw.tile::<f32>(0, i % 16, (i / 16) % 16).unwrap()[5])
        })
    });
    c.bench_function("tile zstd (cache hit)", |b| {
        b.iter(|| {
            i = i.wrapping_add(7);
            black_box(packed.tile::<f32>(0, i % 16, (i / 16) % 16).unwrap()[5])
        })
    });
    c.bench_function("tile zstd decompress (256x256 f32)", |b| {
        let stored = zstd::bulk::compress(raw.tile::<f32>(0, 3, 3).unwrap().as_bytes(), 3).unwrap();
        b.iter(|| black_box(zstd::bulk::decompress(&stored, 1 << 18).unwrap().len()))
    });
    c.bench_function("get post (raw)", |b| {
        b.iter(|| {
            i = i.wrapping_add(7919);
            black_box(raw.get::<f32>(0, i % N, (i / N) % N).unwrap())
        })
    });
    c.bench_function("bilinear sample (raw)", |b| {
        b.iter(|| {
            i = i.wrapping_add(7919);
            black_box(
                raw.bilinear(
                    f64::from(i % (N - 1)) + 0.37,
                    f64::from((i / N) % (N - 1)) + 0.61,
                )
                .unwrap(),
            )
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
