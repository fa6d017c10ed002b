//! The commands that read an asset or write a DEM and run no stage:
//! `info`, `verify` and `synth`.

use std::path::PathBuf;
use std::process::ExitCode;

use crate::io::synth::SynthKind;
use crate::stage::args::parse_size;
use crate::stage::session::{Run, Session};

/// Exit status when `verify` finds problems (1 is any other error, 2 a usage error).
pub const EXIT_VERIFY_FAILED: u8 = 3;

/// `terrabake info`.
#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    /// The asset directory (made by `terrabake ingest` or `terrabake bake`).
    pub asset: PathBuf,
    /// The manifest as JSON, for scripts.
    #[arg(long)]
    pub json: bool,
}

impl Run for InfoArgs {
    fn run(&self, _: &Session) -> crate::Result<ExitCode> {
        print!("{}", crate::present::report::info(&self.asset, self.json)?);
        Ok(ExitCode::SUCCESS)
    }
}

/// `terrabake verify`.
#[derive(clap::Args, Debug)]
pub struct VerifyArgs {
    /// The asset directory (made by `terrabake ingest` or `terrabake bake`).
    pub asset: PathBuf,
    /// Also check that every layer decodes to the same values, bit for bit, as this
    /// asset's (a partitioned bake against one machine's, say).
    #[arg(long, value_name = "OTHER")]
    pub same_as: Option<PathBuf>,
    /// Print the result as JSON on stdout: chunks and layers checked, ok, and the problems (none
    /// when the asset is sound).
    #[arg(long)]
    pub json: bool,
}

impl Run for VerifyArgs {
    /// The report; exit status [`EXIT_VERIFY_FAILED`] when it found problems.
    fn run(&self, _: &Session) -> crate::Result<ExitCode> {
        let (text, good) =
            crate::present::report::verify_asset(&self.asset, self.same_as.as_deref(), self.json)?;
        print!("{text}");
        Ok(if good {
            ExitCode::SUCCESS
        } else {
            ExitCode::from(EXIT_VERIFY_FAILED)
        })
    }
}

/// `terrabake synth`.
#[derive(clap::Args, Debug)]
pub struct SynthArgs {
    /// The terrain to write.
    #[arg(value_enum)]
    pub kind: SynthKind,
    /// WIDTHxHEIGHT in posts.
    #[arg(long, value_parser = parse_size)]
    pub size: (u32, u32),
    /// Seed of the random terrains (the same seed writes the same file).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The GeoTIFF to write.
    #[arg(short, long)]
    pub output: PathBuf,
}

impl Run for SynthArgs {
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let ((w, h), seed) = (self.size, self.seed);
        crate::io::synth::write_geotiff(&self.output, self.kind, w, h, seed, s.progress)?;
        s.say(format!(
            "wrote {} ({w} x {h} {:?}, seed {seed})",
            self.output.display(),
            self.kind
        ));
        Ok(ExitCode::SUCCESS)
    }
}
