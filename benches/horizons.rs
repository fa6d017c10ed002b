//! Horizon algorithms on one core: one line direction and one Stewart
//! sector over a fractal DEM (`cargo bench -p terrabake-bench --bench horizons`). Whole-stage
//! figures come from `terrabake-bench horizons` (docs/BENCHMARKS.md).

use criterion::{criterion_group, criterion_main, Criterion};
use terrabake::algorithms::horizon::line::{grid_direction, line_horizons};
use terrabake::algorithms::horizon::sector::sector_horizons;
use terrabake::io::synth::{height, SynthKind};
use terrabake::terrain::Terrain;

fn fractal(n: usize) -> Vec<f32> {
    let mut z = Vec::with_capacity(n * n);
    for y in 0..n {
        for x in 0..n {
            z.push(height(
                SynthKind::Fractal,
                x as u32,
                y as u32,
                n as u32,
                n as u32,
                1,
            ));
        }
    }
    z
}

fn bench(c: &mut Criterion) {
    let n = 1024;
    let z = fractal(n);
    let t = Terrain::new(&z, n, n, 30.0, 30.0);
    let mut out = vec![0f32; n * n];
    let mut g = c.benchmark_group("horizons_1024");
    g.sample_size(10);
    for az in [0.0, 45.0, 22.5] {
        let dir = grid_direction(az, 30.0, 30.0, 2.8);
        g.bench_function(format!("line {:?}", dir.step), |b| {
            b.iter(|| line_horizons(&t, &dir, &mut out))
        });
    }
    g.bench_function("sector 1 of 16", |b| {
        b.iter(|| sector_horizons(&t, 1, 16, true, &mut out))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
