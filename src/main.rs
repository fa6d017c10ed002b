//! The `terrabake` command line: parse (`terrabake::cli`), dispatch to the
//! library, print (`terrabake::present::report` for people, `--json` for scripts).

use std::path::Path;
use std::process::ExitCode;

use anyhow::Result;
use terrabake::bake::partition::{assemble, bake_part, Part};
use terrabake::bake::recipe::{bake, Recipe};
use terrabake::cli::{Cli, Command};
use terrabake::plumbing::progress::Progress;
use terrabake::present::report::describe_outcome;
use terrabake::stage::asset::{open as open_asset, AssetWriter, Wait};
use terrabake::stage::{run_stage_in, run_stages_in, Stage, StageOutcome};
use terrabake::stages::ingest::IngestStage;
use terrabake::stages::pyramid::PyramidStage;
use terrabake_format::cones::CONE_APEX;
use terrabake_format::horizons::HORIZON;

/// Exit status when `verify` finds problems (1 is any other error, 2 a usage error).
const EXIT_VERIFY_FAILED: u8 = 3;

fn main() -> ExitCode {
    // A closed pipe (`terrabake info --json | head -1`) ends the process
    // quietly, as it does `cat`, instead of a panic in println!.
    // SAFETY: restoring a signal's default disposition before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse_checked();
    terrabake::plumbing::interrupt::install();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", terrabake::error::error_chain(&e));
            ExitCode::FAILURE
        }
    }
}

/// What every command shares: progress bars, whether to wait for another
/// writer, and the messages on stderr (none with `--quiet`).
struct Session {
    progress: Progress,
    wait: Wait,
    quiet: bool,
}

impl Session {
    fn say(&self, msg: String) {
        if !self.quiet {
            eprintln!("{msg}");
        }
    }

    fn run_stage(&self, asset: &Path, stage: &dyn Stage, force: bool) -> Result<StageOutcome> {
        let writer = AssetWriter::open(asset, self.wait)?;
        Ok(run_stage_in(&writer, stage, force, self.progress)?)
    }

    /// Runs `stage` on `asset` and reports its outcome: its JSON record on
    /// stdout (with --json), a line on stderr.
    fn run_and_report(
        &self,
        asset: &Path,
        stage: &dyn Stage,
        force: bool,
        json: bool,
    ) -> Result<()> {
        let outcome = self.run_stage(asset, stage, force)?;
        if json {
            println!("{}", serde_json::to_string_pretty(&outcome)?);
        }
        self.say(describe_outcome(&outcome));
        Ok(())
    }

    /// Several stages' outcomes: a JSON array (with --json), a line each.
    fn report_all(&self, outcomes: &[StageOutcome], json: bool) -> Result<()> {
        if json {
            println!("{}", serde_json::to_string_pretty(outcomes)?);
        }
        outcomes.iter().for_each(|o| self.say(describe_outcome(o)));
        Ok(())
    }
}

fn run(cli: Cli) -> Result<ExitCode> {
    terrabake::plumbing::simd::cap_from_env().map_err(anyhow::Error::msg)?;
    let s = Session {
        progress: Progress::new(cli.quiet),
        wait: Wait::unless(cli.no_wait),
        quiet: cli.quiet,
    };
    let say = |msg: String| s.say(msg);
    match cli.command {
        Command::Page(args) => args.run(&say)?,
        Command::Viewshed(args) => args.run(&say)?,
        Command::Profile(args) => args.run()?,
        Command::TotalViewshed(c) => s.run_and_report(&c.asset, &c.stage, c.force, c.json)?,
        Command::Check(args) => return args.run(s.progress),
        Command::Plan(args) => args.run(s.progress)?,
        Command::Ingest {
            src,
            output,
            opts,
            json,
        } => ingest(&s, src, output, opts, json)?,
        Command::Info { asset, json } => {
            print!("{}", terrabake::present::report::info(&asset, json)?)
        }
        Command::Verify {
            asset,
            same_as,
            json,
        } => {
            let (text, good) =
                terrabake::present::report::verify_asset(&asset, same_as.as_deref(), json)?;
            print!("{text}");
            if !good {
                return Ok(ExitCode::from(EXIT_VERIFY_FAILED));
            }
        }
        Command::Export(args) => args.run(s.progress, &say)?,
        Command::Synth {
            kind,
            size,
            seed,
            output,
        } => {
            terrabake::io::synth::write_geotiff(&output, kind, size.0, size.1, seed, s.progress)?;
            s.say(format!(
                "wrote {} ({} x {} {:?}, seed {seed})",
                output.display(),
                size.0,
                size.1,
                kind
            ));
        }
        Command::Render(args) => args.run(&say)?,
        Command::Pyramid { asset, force, json } => {
            s.run_and_report(&asset, &PyramidStage, force, json)?;
        }
        Command::Cones {
            asset,
            stage,
            force,
            json,
        } => cones(&s, &asset, &stage, force, json)?,
        Command::Sky(c) => s.run_and_report(&c.asset, &c.stage, c.force, c.json)?,
        Command::Horizons {
            asset,
            stage,
            no_sky,
            force,
            json,
        } => horizons(&s, &asset, &stage, no_sky, force, json)?,
        Command::Bake {
            src,
            output,
            recipe,
            request,
            parts,
            part,
            json,
        } => {
            let (wait, progress) = (s.wait, s.progress);
            let outcomes = match (recipe, request.request(), part.zip(parts)) {
                (Some(r), _, Some((i, n))) => bake_part(
                    &src,
                    &output,
                    &Recipe::load(&r)?,
                    Part::new(i, n)?,
                    wait,
                    progress,
                )?,
                (Some(r), ..) => bake(&src, &output, &Recipe::load(&r)?, wait, progress)?,
                (None, plan, _) => {
                    let recipe = Recipe {
                        plan,
                        ..Default::default()
                    };
                    bake(&src, &output, &recipe, wait, progress)?
                }
            };
            s.report_all(&outcomes, json)?;
        }
        Command::Assemble {
            asset,
            keep_parts,
            json,
        } => s.report_all(&assemble(&asset, keep_parts, s.wait, s.progress)?, json)?,
    }
    Ok(ExitCode::SUCCESS)
}

/// `terrabake ingest`: the asset created, its manifest (with --json) and a
/// summary line.
fn ingest(
    s: &Session,
    src: std::path::PathBuf,
    output: std::path::PathBuf,
    options: terrabake::stages::ingest::IngestOptions,
    json: bool,
) -> Result<()> {
    let start = std::time::Instant::now();
    let stage = IngestStage {
        src: src.clone(),
        options,
    };
    run_stage_in(
        &AssetWriter::create(&output, s.wait)?,
        &stage,
        true,
        s.progress,
    )?;
    let manifest = open_asset(&output)?.manifest().clone();
    if json {
        println!("{}", serde_json::to_string_pretty(&manifest)?);
    }
    s.say(terrabake::present::report::ingested(
        &src,
        &output,
        &manifest,
        start.elapsed(),
    ));
    Ok(())
}

/// `terrabake cones`: the stage's outcome and how it sliced the planes.
fn cones(
    s: &Session,
    asset: &Path,
    stage: &terrabake::stages::cones::ConesStage,
    force: bool,
    json: bool,
) -> Result<()> {
    let outcome = s.run_stage(asset, stage, force)?;
    let how = open_asset(asset)?
        .manifest()
        .layer(CONE_APEX, 0)
        .map(|l| l.description.clone())
        .unwrap_or_default();
    if json {
        let mut v = serde_json::to_value(&outcome)?;
        v["planes"] = serde_json::Value::String(how.clone());
        println!("{}", serde_json::to_string_pretty(&v)?);
    }
    s.say(describe_outcome(&outcome));
    s.say(how);
    Ok(())
}

/// `terrabake horizons`: the horizons and, unless `no_sky`, the sky layers,
/// in one run: the sky layers the new horizons drop are committed again
/// with them, so no reader finds them missing meanwhile.
fn horizons(
    s: &Session,
    asset: &Path,
    stage: &terrabake::stages::horizons::HorizonsStage,
    no_sky: bool,
    force: bool,
    json: bool,
) -> Result<()> {
    let sky = terrabake::stages::sky::SkyStage::default();
    let mut stages: Vec<(&dyn Stage, bool)> = vec![(stage, force)];
    if !no_sky {
        stages.push((&sky, false));
    }
    let writer = AssetWriter::open(asset, s.wait)?;
    let outcomes = run_stages_in(&writer, &stages, s.progress, &mut |_| Ok(()))?;
    drop(writer);
    let outcome = &outcomes[0];
    let entry = open_asset(asset)?.manifest().layer(HORIZON, 0).cloned();
    if json {
        let v = terrabake::present::report::horizons_json(outcome, entry.as_ref())?;
        println!("{}", serde_json::to_string_pretty(&v)?);
    }
    s.say(describe_outcome(outcome));
    if let Some(e) = entry {
        s.say(e.description);
    }
    outcomes[1..]
        .iter()
        .for_each(|o| s.say(describe_outcome(o)));
    Ok(())
}
