//! The planner: on every synthetic terrain and random budgets, a planned
//! bake meets its horizon and svf budget when `check` measures it on posts
//! the plan never saw; a looser budget never costs more; a budget that
//! cannot be met is refused, naming what to relax, and leaves nothing.

mod common;

use std::path::Path;

use common::*;
use proptest::prelude::*;
use terrabake::budget::Budget;
use terrabake::check::{check, CheckOptions};
use terrabake::ingest::IngestOptions;
use terrabake::plan::{plan, Plan};
use terrabake::progress::Progress;
use terrabake::sky::SkyStage;
use terrabake::stage::run_stage;
use terrabake::synth::SynthKind;
use terrabake_format::Asset;

fn terrain(dir: &Path, kind: SynthKind, seed: u64) -> std::path::PathBuf {
    synth_with_pyramid(dir, kind, 64, 48, seed, IngestOptions::default())
}

fn planned(asset: &Path, budget: &Budget) -> Plan {
    plan(&Asset::open(asset).unwrap(), budget, Progress::hidden()).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(5))]
    #[test]
    fn planned_bakes_meet_their_budget(
        kind in prop::sample::select(SynthKind::ALL.to_vec()),
        horizon in 0.3f64..6.0,
        svf in prop::option::of(0.002f64..0.05),
        seed in 0u64..1000,
    ) {
        let dir = tempfile::tempdir().unwrap();
        let asset = terrain(dir.path(), kind, seed);
        let budget = Budget { horizon, svf, ..Default::default() };
        let plan = match plan(&Asset::open(&asset).unwrap(), &budget, Progress::hidden()) {
            Ok(plan) => plan,
            // Refused: only when even the most directions leave too much.
            Err(e) => {
                prop_assert!(format!("{e:#}").contains("relax horizon"), "{e:#}");
                return Ok(());
            }
        };
        run_stage(&asset, &plan.horizons_stage(), true, Progress::hidden()).unwrap();
        run_stage(&asset, &SkyStage::default(), true, Progress::hidden()).unwrap();
        let report = check(
            &Asset::open(&asset).unwrap(),
            &CheckOptions { samples: 160, seed: seed + 7, directions: 720 },
            Some(&budget),
            Progress::hidden(),
        )
        .unwrap();
        prop_assert!(report.within_budget(), "{kind:?} {budget}: planned {:?}, achieved {report:?}", plan.chosen);
    }
}

#[test]
fn a_looser_budget_never_costs_more() {
    for kind in [SynthKind::Fractal, SynthKind::Holes] {
        let dir = tempfile::tempdir().unwrap();
        let asset = terrain(dir.path(), kind, 5);
        let mut last: Option<Plan> = None;
        for horizon in [0.5, 1.0, 2.0, 4.0] {
            let p = planned(
                &asset,
                &Budget {
                    horizon,
                    svf: Some(horizon / 100.0),
                    ..Default::default()
                },
            );
            if let Some(tighter) = &last {
                let (a, b) = (&tighter.chosen, &p.chosen);
                assert!(
                    b.sectors <= a.sectors && b.bytes <= a.bytes && b.seconds <= a.seconds,
                    "{kind:?}: {horizon} deg costs more than the tighter budget: {b:?} against {a:?}"
                );
            }
            last = Some(p);
        }
        let (tightest, loosest) = (
            planned(
                &asset,
                &Budget {
                    horizon: 0.5,
                    ..Default::default()
                },
            ),
            last.unwrap(),
        );
        assert!(loosest.chosen.sectors < tightest.chosen.sectors, "{kind:?}");
    }
}

#[test]
fn budgets_that_cannot_be_met_are_refused_naming_what_to_relax() {
    let dir = tempfile::tempdir().unwrap();
    let asset = terrain(dir.path(), SynthKind::Noise, 2);
    let refused = |budget: &str| {
        let e = plan(
            &Asset::open(&asset).unwrap(),
            &budget.parse().unwrap(),
            Progress::hidden(),
        )
        .unwrap_err();
        format!("{e:#}")
    };
    let message = refused("horizon=0.0001");
    let (_, suggested) = message
        .split_once("relax horizon to at least ")
        .unwrap_or_else(|| panic!("{message}"));
    // Relaxed to what it says, the budget is met.
    let enough: f64 = suggested.trim().parse().unwrap();
    planned(
        &asset,
        &Budget {
            horizon: enough,
            ..Default::default()
        },
    );
    assert!(refused("horizon=2,bytes=1K").contains("relax bytes"));
    // From the command line: refused, and the asset it would have made is
    // not left behind.
    let tif = dir.path().join("t.tif");
    let out = dir.path().join("new.tbake");
    let result = terrabake(&[
        "bake",
        tif.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--budget",
        "horizon=2,bytes=1K",
    ]);
    assert_eq!(result.status.code(), Some(1), "{}", stderr(&result));
    assert!(
        stderr(&result).contains("relax bytes"),
        "{}",
        stderr(&result)
    );
    assert!(!out.exists());
    // A recipe and a budget at once, or a bad budget: usage errors.
    let both = terrabake(&[
        "bake",
        "x.tif",
        "-o",
        "y",
        "--budget",
        "horizon=1",
        "--recipe",
        "r.toml",
    ]);
    assert_eq!(both.status.code(), Some(2));
    let bad = terrabake(&["bake", "x.tif", "-o", "y", "--budget", "horizon=1,sfv=2"]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(
        stderr(&bad).contains("not a budget key"),
        "{}",
        stderr(&bad)
    );
}

#[test]
fn bake_to_a_budget_then_check_it() {
    let dir = tempfile::tempdir().unwrap();
    let _ = terrain(dir.path(), SynthKind::Fractal, 9);
    let tif = dir.path().join("t.tif");
    let out = dir.path().join("planned.tbake");
    let o = out.to_str().unwrap();
    let bake = terrabake(&[
        "bake",
        tif.to_str().unwrap(),
        "-o",
        o,
        "--budget",
        "horizon=1,svf=0.01",
        "-q",
    ]);
    assert!(bake.status.success(), "{}", stderr(&bake));
    // The check takes the recorded budget and shows the plan's prediction.
    let checked = terrabake(&["check", o, "--samples", "200"]);
    assert_eq!(
        checked.status.code(),
        Some(0),
        "{}{}",
        stdout(&checked),
        stderr(&checked)
    );
    let text = stdout(&checked);
    assert!(
        text.contains("planned")
            && text.contains("budget horizon=1,svf=0.01")
            && text.contains("met"),
        "{text}"
    );
}
