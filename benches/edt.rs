//! The exact distance transform of one slice plane (groundwork for the cone
//! stage): `cargo bench -p terrabake-bench --bench edt`.

use criterion::{criterion_group, criterion_main, Criterion};

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("edt");
    group.sample_size(10);
    for n in [1024usize, 8192] {
        // About one cell in 97 is a site, spread by a multiplicative hash.
        let site: Vec<bool> = (0..n * n)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 7) % 97 == 0)
            .collect();
        group.bench_function(format!("squared_2d {n}x{n}"), |b| {
            b.iter(|| terrabake::algorithms::edt::squared_2d(&site, n, n, 30.0, 30.0))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
