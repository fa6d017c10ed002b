//! Writers and readers at the same time: the writer lock, readers during
//! commits, and the reclaiming of garbage (docs/RELIABILITY.md).

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

mod common;

use terrabake_format::manifest::*;
use terrabake_format::*;
use zerocopy::IntoBytes;

const N: u32 = 40;
const TS: u32 = 16;

/// A height layer whose every post is `value`.
fn height_layer(dir: &Path, value: f32) -> LayerEntry {
    let spec = LayerSpec {
        name: HEIGHT_LAYER.into(),
        level: 0,
        elem: ElemType::F32,
        bands: 1,
        width: N,
        height: N,
        tile_size: TS,
        codec: Codec::Raw,
        fill_bits: u64::from(f32::NAN.to_bits()),
        stage: "test".into(),
        description: String::new(),
    };
    let mut w = LayerWriter::create(dir, spec.clone()).unwrap();
    let tile = vec![value; (TS * TS) as usize];
    for _ in 0..spec.chunk_count() {
        w.push(encode_tile(tile.as_bytes(), 4, Codec::Raw, 0))
            .unwrap();
    }
    w.finish().unwrap()
}

fn manifest(layer: LayerEntry, value: f32) -> Manifest {
    common::manifest(
        (N, N, TS),
        (1.0, 1.0),
        vec![layer],
        0,
        Some(HeightRange {
            min: value,
            max: value,
        }),
    )
}

fn commit_generation(lock: &WriteLock, value: f32) -> Manifest {
    let layer = height_layer(lock.dir(), value);
    commit_manifest(lock, &manifest(layer, value)).unwrap()
}

#[test]
fn a_reader_looping_during_1000_commits_never_fails() {
    readers_during_commits(DEFAULT_RETIRE_GRACE_FOR_TEST);
}

/// With no grace at all, old files go at the very commit that retires them:
/// the reader's retry on a changed manifest alone must carry it.
#[test]
fn readers_survive_commits_without_a_grace_period() {
    readers_during_commits(Duration::ZERO);
}

const DEFAULT_RETIRE_GRACE_FOR_TEST: Duration = terrabake_format::writer::DEFAULT_RETIRE_GRACE;

fn readers_during_commits(grace: Duration) {
    let dir = tempfile::tempdir().unwrap();
    let lock = WriteLock::acquire(dir.path(), false, |_| {})
        .unwrap()
        .with_grace(grace);
    commit_generation(&lock, 0.0);
    let done = AtomicBool::new(false);
    let (reads, failures) = (AtomicU64::new(0), AtomicU64::new(0));
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| {
                while !done.load(Ordering::Acquire) {
                    let result = Asset::open(dir.path()).and_then(|asset| {
                        // One whole generation: every post of every tile
                        // holds the value the manifest's range states.
                        let want = asset.manifest().height_range.unwrap().min;
                        let h = asset.height()?;
                        for ty in 0..h.tiles_y() {
                            for tx in 0..h.tiles_x() {
                                let tile = h.tile::<f32>(0, tx, ty)?;
                                assert!(tile.iter().all(|&z| z == want), "mixed generations");
                            }
                        }
                        Ok(())
                    });
                    reads.fetch_add(1, Ordering::Relaxed);
                    if let Err(e) = result {
                        eprintln!("reader failed: {e}");
                        failures.fetch_add(1, Ordering::Relaxed);
                    }
                }
            });
        }
        for generation in 1..=1000 {
            commit_generation(&lock, generation as f32);
        }
        done.store(true, Ordering::Release);
    });
    let (reads, failures) = (reads.into_inner(), failures.into_inner());
    eprintln!("grace {grace:?}: {reads} reads during 1000 commits, {failures} failed");
    assert_eq!(failures, 0);
    assert!(reads > 100, "readers barely ran ({reads} reads)");
}

#[test]
fn a_second_writer_is_refused_naming_the_holder_or_waits() {
    let dir = tempfile::tempdir().unwrap();
    let held = WriteLock::acquire(dir.path(), false, |_| {}).unwrap();
    match WriteLock::acquire(dir.path(), false, |_| {}) {
        Err(Error::Locked { pid, .. }) => assert_eq!(pid, Some(std::process::id())),
        other => panic!("second writer not refused: {other:?}"),
    }
    let msg = WriteLock::acquire(dir.path(), false, |_| {})
        .unwrap_err()
        .to_string();
    assert!(msg.contains(&std::process::id().to_string()), "{msg}");
    // A waiting writer is told who holds it, and gets it once released.
    std::thread::scope(|s| {
        let waiter = s.spawn(|| {
            let mut told = None;
            let lock = WriteLock::acquire(dir.path(), true, |pid| told = Some(pid)).unwrap();
            (lock, told)
        });
        std::thread::sleep(Duration::from_millis(100));
        drop(held);
        let (_lock, told) = waiter.join().unwrap();
        assert_eq!(told, Some(Some(std::process::id())));
    });
}

#[test]
fn garbage_is_reclaimed_and_retired_files_kept_for_their_grace() {
    let dir = tempfile::tempdir().unwrap();
    let lock = WriteLock::acquire(dir.path(), false, |_| {}).unwrap();
    let first = commit_generation(&lock, 1.0);
    let second = commit_generation(&lock, 2.0);
    // The first generation's file is retired, not gone: a reader that read
    // the first manifest a moment ago still finds it.
    let old = &first.layers[0].file;
    assert!(dir.path().join(old).exists());
    assert_eq!(second.retired.len(), 1);
    assert_eq!(&second.retired[0].file, old);
    // A dead writer's leftovers: a temporary and an orphan layer file.
    let tmp = dir.path().join("height.L0.g7.tbl.999-0-0000abcd.tmp");
    let orphan = dir.path().join("height.L0.g7.tbl");
    let foreign = dir.path().join("notes.txt");
    for f in [&tmp, &orphan, &foreign] {
        std::fs::write(f, b"x").unwrap();
    }
    drop(lock);
    let lock = WriteLock::acquire(dir.path(), false, |_| {}).unwrap();
    let removed = lock.reclaim_garbage().unwrap();
    assert_eq!(
        removed,
        vec![
            "height.L0.g7.tbl".to_string(),
            "height.L0.g7.tbl.999-0-0000abcd.tmp".to_string()
        ]
    );
    assert!(foreign.exists(), "a file not ours is never touched");
    assert!(dir.path().join(old).exists(), "still within its grace");
    // Past the grace, the next commit removes it.
    let lock = lock.with_grace(Duration::ZERO);
    let third = commit_generation(&lock, 3.0);
    assert!(!dir.path().join(old).exists());
    assert!(!dir.path().join(&second.layers[0].file).exists());
    assert!(third.retired.is_empty());
    Asset::open(dir.path()).unwrap();
}

#[test]
fn an_unreadable_manifest_stops_reclaiming() {
    // Garbage cannot be told from the asset without a manifest to read:
    // nothing is removed then.
    let dir = tempfile::tempdir().unwrap();
    let lock = WriteLock::acquire(dir.path(), false, |_| {}).unwrap();
    let m = commit_generation(&lock, 1.0);
    std::fs::write(dir.path().join(MANIFEST_FILE), b"garbage").unwrap();
    assert!(lock.reclaim_garbage().unwrap().is_empty());
    assert!(dir.path().join(&m.layers[0].file).exists());
}
