//! The fuzz targets (`tests/fuzz/targets.rs`) for a fixed number of
//! iterations with a fixed seed, so `make test` runs them the same way
//! every time; `make fuzz` runs them coverage-guided for longer. Inputs are
//! the seeds mutated by a small deterministic mutator: no panic, abort or
//! hang is allowed, and a source that ingests must verify.

#[path = "fuzz/targets.rs"]
mod targets;

use std::panic::{catch_unwind, AssertUnwindSafe};

/// Iterations per target in `make test`; `FUZZ_ITERATIONS` overrides.
const ITERATIONS: u64 = 20000;

fn iterations() -> u64 {
    std::env::var("FUZZ_ITERATIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(ITERATIONS)
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

#[test]
fn reader_survives_mutated_assets() {
    let dir = tempfile::tempdir().unwrap();
    let seed = targets::seed_asset(dir.path());
    let mut rng = Rng(0x7e77_ab4e);
    let (mut panics, mut opened) = (Vec::new(), 0);
    let n = iterations();
    for i in 0..n {
        let ops: Vec<u8> = (0..8 * (1 + rng.below(6)))
            .map(|_| rng.next() as u8)
            .collect();
        match catch_unwind(AssertUnwindSafe(|| targets::reader(&seed, &ops))) {
            Ok(true) => opened += 1,
            Ok(false) => {}
            Err(_) => panics.push((i, ops)),
        }
    }
    eprintln!(
        "reader: {n} mutated assets, {opened} opened and read, {} panics",
        panics.len()
    );
    assert!(
        opened > n / 20,
        "too few mutants get past the checks: {opened}"
    );
    assert!(
        panics.is_empty(),
        "panics on inputs {:?}",
        &panics[..panics.len().min(3)]
    );
}

#[test]
fn ingest_survives_mutated_sources() {
    let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/tiff");
    let mut seeds: Vec<Vec<u8>> = std::fs::read_dir(&fixtures)
        .unwrap()
        .map(|e| std::fs::read(e.unwrap().path()).unwrap())
        .collect();
    seeds.sort();
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng(0x1a6e_57a1);
    let (mut panics, mut ingested) = (Vec::new(), 0);
    let n = iterations() / 4;
    for i in 0..n {
        let mut data = seeds[rng.below(seeds.len())].clone();
        for _ in 0..1 + rng.below(4) {
            let at = rng.below(data.len());
            match rng.below(4) {
                0 => data[at] = rng.next() as u8,
                1 => data[at] ^= 1 << rng.below(8),
                2 => data.truncate(at.max(8)),
                // Header fields live early: hit them more often.
                _ => {
                    let at = rng.below(data.len().min(256));
                    data[at] = [0, 0xff, 0x7f, 0x80, 1][rng.below(5)];
                }
            }
        }
        match catch_unwind(AssertUnwindSafe(|| {
            targets::ingest(&data, "tif", dir.path())
        })) {
            Ok(true) => ingested += 1,
            Ok(false) => {}
            Err(_) => panics.push(i),
        }
    }
    eprintln!(
        "ingest: {n} mutated sources, {ingested} ingested and verified, {} panics",
        panics.len()
    );
    assert!(panics.is_empty(), "panics on iterations {panics:?}");
}
