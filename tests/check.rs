//! `terrabake check` measures what a bake achieved against exact references
//! from the heights alone: a bake that stores the reference's own
//! directions exactly checks to (almost) nothing on every synthetic terrain,
//! fewer bands check worse, a budget that is not met exits 4 and names the
//! limit, and the result is recorded in the manifest until the horizons are
//! baked again.

mod common;

use std::path::{Path, PathBuf};

use common::*;
use terrabake::io::synth::SynthKind;
use terrabake::plan::check::{check, CheckOptions};
use terrabake::plumbing::progress::Progress;
use terrabake::stage::run_stage;
use terrabake::stages::horizons::HorizonsStage;
use terrabake::stages::ingest::IngestOptions;
use terrabake::stages::sky::SkyStage;
use terrabake_format::horizons::AngleEncoding;
use terrabake_format::Asset;

/// A synthetic terrain with horizons of `sectors` line directions.
fn baked(
    dir: &Path,
    kind: SynthKind,
    sectors: usize,
    tolerance: Option<f64>,
    encoding: AngleEncoding,
) -> PathBuf {
    let asset = synth_with_pyramid(dir, kind, 48, 40, 7, IngestOptions::default());
    let stage = HorizonsStage {
        sectors,
        direction_tolerance: tolerance,
        encoding: Some(encoding),
        ..Default::default()
    };
    run_stage(&asset, &stage, true, Progress::hidden()).unwrap();
    run_stage(&asset, &SkyStage::default(), true, Progress::hidden()).unwrap();
    asset
}

fn options(directions: usize) -> CheckOptions {
    CheckOptions {
        samples: 80,
        seed: 3,
        directions,
        cuts: &[],
    }
}

#[test]
fn a_bake_of_the_references_own_directions_checks_to_nothing_on_every_terrain() {
    for kind in SynthKind::ALL {
        let dir = tempfile::tempdir().unwrap();
        // The stage picks the same grid directions as the reference (same
        // count, same tolerance) and stores f32: the fast sweep against the
        // brute force, and the interpolation at the stored azimuths, exact.
        let asset = baked(dir.path(), kind, 180, Some(0.1), AngleEncoding::F32);
        let report = check(
            &Asset::open(&asset).unwrap(),
            &options(180),
            None,
            &[],
            Progress::hidden(),
        )
        .unwrap();
        let report = report.horizons.expect("horizons checked");
        assert!(report.posts >= 80, "{kind:?}: {} posts", report.posts);
        assert!(
            report.horizon_p99_deg < 1e-3 && report.horizon_max_deg < 1e-2,
            "{kind:?}: {report:?}"
        );
        assert!(report.svf_max.unwrap() < 1e-4, "{kind:?}: {report:?}");
    }
}

#[test]
fn fewer_bands_check_worse() {
    let p99 = |sectors| {
        let dir = tempfile::tempdir().unwrap();
        let asset = baked(
            dir.path(),
            SynthKind::Fractal,
            sectors,
            None,
            AngleEncoding::F32,
        );
        check(
            &Asset::open(&asset).unwrap(),
            &options(360),
            None,
            &[],
            Progress::hidden(),
        )
        .unwrap()
        .horizons
        .unwrap()
        .horizon_p99_deg
    };
    let (few, many) = (p99(8), p99(64));
    assert!(
        few > 2.0 * many && many > 0.0,
        "8 bands {few}, 64 bands {many}"
    );
}

#[test]
fn a_budget_not_met_exits_4_and_the_result_is_recorded_until_a_rebake() {
    let dir = tempfile::tempdir().unwrap();
    let asset = baked(dir.path(), SynthKind::Spike, 8, None, AngleEncoding::U8);
    let a = asset.to_str().unwrap();
    let check_with = |budget: &str, more: &[&str]| {
        let mut args = vec![
            "check",
            a,
            "--samples",
            "40",
            "--directions",
            "90",
            "--budget",
            budget,
        ];
        args.extend_from_slice(more);
        terrabake(&args)
    };
    let out = check_with("horizon=0.001", &[]);
    assert_eq!(out.status.code(), Some(4), "{}", stderr(&out));
    assert!(stdout(&out).contains("EXCEEDED"), "{}", stdout(&out));
    let out = check_with("horizon=89", &["--json"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["verdicts"][0]["met"], serde_json::Value::Bool(true));
    let recorded = |asset: &Path| {
        Asset::open(asset)
            .unwrap()
            .manifest()
            .provenance
            .stages
            .iter()
            .any(|r| r.stage == "check")
    };
    assert!(recorded(&asset));
    // Baking the horizons again drops the measurement of the old ones.
    let stage = HorizonsStage {
        sectors: 12,
        ..Default::default()
    };
    run_stage(&asset, &stage, true, Progress::hidden()).unwrap();
    assert!(!recorded(&asset));
    // --no-record measures and leaves the manifest alone.
    let out = terrabake(&["check", a, "--samples", "10", "--no-record", "-q"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(!recorded(&asset));
    // Bad budgets are usage errors that name the key; an asset without
    // horizons says what adds them.
    let out = terrabake(&["check", a, "--budget", "horizon=-1"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("horizon=-1"), "{}", stderr(&out));
    let tif = dir.path().join("t.tif");
    let bare = dir.path().join("bare.tbake");
    let out = terrabake(&[
        "ingest",
        tif.to_str().unwrap(),
        "-o",
        bare.to_str().unwrap(),
        "-q",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let out = terrabake(&["check", bare.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("terrabake horizons"),
        "{}",
        stderr(&out)
    );
}
