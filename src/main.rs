//! The `terrabake` command line: parse (`terrabake::cli`), dispatch to the
//! library, print (`terrabake::present::report` for people, `--json` for scripts).

use std::path::Path;
use std::process::ExitCode;

use anyhow::{bail, Result};
use terrabake::bake::partition::{assemble, bake_part, Part};
use terrabake::bake::recipe::{bake, Recipe};
use terrabake::cli::{Cli, Command};
use terrabake::plumbing::progress::Progress;
use terrabake::present::render::{
    builtin_views, render, write_png, Camera, RenderOptions, Shadows,
};
use terrabake::present::report::describe_outcome;
use terrabake::stage::asset::{open as open_asset, AssetWriter, Wait};
use terrabake::stage::{run_stage_in, run_stages_in, Stage, StageOutcome};
use terrabake::stages::ingest::IngestStage;
use terrabake::stages::pyramid::PyramidStage;
use terrabake_format::cones::CONE_APEX;
use terrabake_format::horizons::HORIZON;
use terrabake_format::trace::Tracer;

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
            eprintln!("error: {}", terrabake::present::report::error_chain(&e));
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<ExitCode> {
    terrabake::plumbing::simd::cap_from_env().map_err(anyhow::Error::msg)?;
    let progress = Progress::new(cli.quiet);
    let wait = Wait::unless(cli.no_wait);
    let run_stage = |asset: &Path, stage: &dyn Stage, force: bool| -> Result<StageOutcome> {
        run_stage_in(&AssetWriter::open(asset, wait)?, stage, force, progress)
    };
    let say = |msg: String| {
        if !cli.quiet {
            eprintln!("{msg}");
        }
    };
    // A stage's outcome: its JSON record on stdout (with --json), a line on stderr.
    let report = |outcome: &StageOutcome, json: bool| -> Result<()> {
        if json {
            println!("{}", serde_json::to_string_pretty(outcome)?);
        }
        say(describe_outcome(outcome));
        Ok(())
    };
    let report_all = |outcomes: &[StageOutcome], json: bool| -> Result<()> {
        if json {
            println!("{}", serde_json::to_string_pretty(outcomes)?);
        }
        outcomes.iter().for_each(|o| say(describe_outcome(o)));
        Ok(())
    };
    match cli.command {
        Command::Page(args) => args.run(&say)?,
        Command::Viewshed(args) => args.run(&say)?,
        Command::Profile(args) => args.run()?,
        Command::TotalViewshed(c) => report(&run_stage(&c.asset, &c.stage, c.force)?, c.json)?,
        Command::Check(args) => return args.run(progress),
        Command::Plan(args) => args.run(progress)?,
        Command::Ingest {
            src,
            output,
            opts,
            json,
        } => {
            let start = std::time::Instant::now();
            let stage = IngestStage {
                src: src.clone(),
                options: opts,
            };
            run_stage_in(&AssetWriter::create(&output, wait)?, &stage, true, progress)?;
            let manifest = open_asset(&output)?.manifest().clone();
            if json {
                println!("{}", serde_json::to_string_pretty(&manifest)?);
            }
            say(terrabake::present::report::ingested(
                &src,
                &output,
                &manifest,
                start.elapsed(),
            ));
        }
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
        Command::Export(args) => args.run(progress, &say)?,
        Command::Synth {
            kind,
            size,
            seed,
            output,
        } => {
            terrabake::io::synth::write_geotiff(&output, kind, size.0, size.1, seed, progress)?;
            say(format!(
                "wrote {} ({} x {} {:?}, seed {seed})",
                output.display(),
                size.0,
                size.1,
                kind
            ));
        }
        Command::Render {
            asset,
            shade: Some(shade),
            output,
            ..
        } => {
            let opened = open_asset(&asset)?;
            terrabake::present::shade::write_shade_png(&opened, shade, &output, 4096)?;
            say(format!("wrote {}", output.display()));
        }
        Command::Render {
            asset,
            shade: None,
            camera,
            look_at,
            view,
            fov,
            size,
            method,
            sun,
            every,
            no_shadows,
            horizon_shadows,
            exaggerate,
            normals,
            output,
            stats,
            json,
        } => {
            let opened = open_asset(&asset)?;
            let tracer = Tracer::new(&opened)?;
            terrabake::present::render::require_layers(&tracer, method, &asset)?;
            let mut cam = match (view, camera, look_at) {
                (Some(v), _, _) => builtin_views(&tracer, &opened)[v as usize - 1],
                (None, Some(eye), Some(look_at)) => Camera {
                    eye,
                    look_at,
                    fov: 60.0,
                },
                _ => bail!("give --view N, or --camera X,Y,Z and --look-at X,Y,Z"),
            };
            cam.fov = fov.unwrap_or(cam.fov);
            let opts = RenderOptions {
                width: size.0,
                height: size.1,
                method,
                sun,
                every,
                shadows: match (no_shadows, horizon_shadows) {
                    (true, _) => Shadows::Off,
                    (false, true) => Shadows::Horizons,
                    (false, false) => Shadows::Rays,
                },
                exaggeration: exaggerate,
                normals,
            };
            let (image, st) = render(&opened, &tracer, &cam, &opts)?;
            write_png(&output, &image)?;
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(
                        &serde_json::json!({ "camera": cam, "method": method.name(), "stats": st })
                    )?
                );
            } else if stats {
                println!(
                    "{}",
                    terrabake::present::report::render_stats(method.name(), &st)
                );
            }
            say(format!("wrote {}", output.display()));
        }
        Command::Pyramid { asset, force, json } => {
            report(&run_stage(&asset, &PyramidStage, force)?, json)?;
        }
        Command::Cones {
            asset,
            stage,
            force,
            json,
        } => {
            let outcome = run_stage(&asset, &stage, force)?;
            let how = open_asset(&asset)?
                .manifest()
                .layer(CONE_APEX, 0)
                .map(|l| l.description.clone())
                .unwrap_or_default();
            if json {
                let mut v = serde_json::to_value(&outcome)?;
                v["planes"] = serde_json::Value::String(how.clone());
                println!("{}", serde_json::to_string_pretty(&v)?);
            }
            say(describe_outcome(&outcome));
            say(how);
        }
        Command::Sky(c) => report(&run_stage(&c.asset, &c.stage, c.force)?, c.json)?,
        Command::Horizons {
            asset,
            stage,
            no_sky,
            force,
            json,
        } => {
            // One run: the sky layers the new horizons drop are committed
            // again with them, so no reader finds them missing meanwhile.
            let sky = terrabake::stages::sky::SkyStage::default();
            let mut stages: Vec<(&dyn Stage, bool)> = vec![(&stage, force)];
            if !no_sky {
                stages.push((&sky, false));
            }
            let outcomes = run_stages_in(
                &AssetWriter::open(&asset, wait)?,
                &stages,
                progress,
                &mut |_| Ok(()),
            )?;
            let outcome = outcomes[0].clone();
            let opened = open_asset(&asset)?;
            let entry = opened.manifest().layer(HORIZON, 0).cloned();
            if json {
                let v = terrabake::present::report::horizons_json(&outcome, entry.as_ref())?;
                println!("{}", serde_json::to_string_pretty(&v)?);
            }
            say(describe_outcome(&outcome));
            if let Some(e) = entry {
                say(e.description);
            }
            outcomes[1..].iter().for_each(|o| say(describe_outcome(o)));
        }
        Command::Bake {
            src,
            output,
            recipe,
            request,
            parts,
            part,
            json,
        } => {
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
            report_all(&outcomes, json)?;
        }
        Command::Assemble {
            asset,
            keep_parts,
            json,
        } => report_all(&assemble(&asset, keep_parts, wait, progress)?, json)?,
    }
    Ok(ExitCode::SUCCESS)
}
