//! The one shape of a `terrabake` command: its arguments are one clap
//! `Args` type that implements [`Run`], and [`Run::run`] does the work with
//! what every command shares, a [`Session`]: progress bars, whether to wait
//! for another writer of the asset, and the summary lines on stderr (none
//! with `--quiet`). The grammar (`crate::cli`) lists the commands and
//! dispatches each in one line; the binary prints the error a run returns.
//!
//! It lives with the stage interface, beneath every room whose commands
//! implement it (plan, present, export), because running one stage on an
//! asset and reporting it is what most commands do.

use std::path::Path;
use std::process::ExitCode;

use crate::plumbing::progress::Progress;
use crate::stage::asset::{AssetWriter, Wait};
use crate::stage::{run_stage_in, Stage, StageOutcome};

/// What every command shares.
#[derive(Debug, Clone, Copy)]
pub struct Session {
    /// Progress bars (hidden with `--quiet` or when stderr is no terminal).
    pub progress: Progress,
    /// Whether a writer waits for another process writing the asset.
    pub wait: Wait,
    /// No summary lines on stderr.
    pub quiet: bool,
}

impl Session {
    /// A session that shows progress and messages unless `quiet`, and
    /// waits for another writer unless `no_wait` (the global flags).
    pub fn new(quiet: bool, no_wait: bool) -> Self {
        Self {
            progress: Progress::new(quiet),
            wait: Wait::unless(no_wait),
            quiet,
        }
    }

    /// A summary line on stderr, unless quiet.
    pub fn say(&self, msg: impl AsRef<str>) {
        if !self.quiet {
            eprintln!("{}", msg.as_ref());
        }
    }

    /// Runs `stage` on the existing asset `asset` under its writer lock.
    pub fn run_stage(
        &self,
        asset: &Path,
        stage: &dyn Stage,
        force: bool,
    ) -> crate::Result<StageOutcome> {
        let writer = AssetWriter::open(asset, self.wait)?;
        run_stage_in(&writer, stage, force, self.progress)
    }

    /// Stages' outcomes reported: a JSON array (with `json`) on stdout,
    /// a line each on stderr.
    pub fn report_all(&self, outcomes: &[StageOutcome], json: bool) -> crate::Result<()> {
        if json {
            println!("{}", serde_json::to_string_pretty(outcomes)?);
        }
        outcomes.iter().for_each(|o| self.say(o.to_string()));
        Ok(())
    }
}

/// A command's arguments, run: what `terrabake NAME ...` does.
pub trait Run {
    /// Does the command's work; the exit status is success unless the
    /// command says otherwise (`verify` and `check` have their own).
    fn run(&self, session: &Session) -> crate::Result<ExitCode>;
}
