//! The `terrabake` command line: parse (`terrabake::cli`), run the command
//! (each command's arguments run themselves, `terrabake::stage::session`),
//! and print what failed.

use std::process::ExitCode;

use terrabake::cli::Cli;
use terrabake::stage::session::Session;

fn main() -> ExitCode {
    // A closed pipe (`terrabake info --json | head -1`) ends the process
    // quietly, as it does `cat`, instead of a panic in println!.
    // SAFETY: restoring a signal's default disposition before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse_checked();
    terrabake::plumbing::interrupt::install();
    terrabake::plumbing::resources::own_the_allocator();
    let run = || {
        terrabake::plumbing::simd::cap_from_env().map_err(anyhow::Error::msg)?;
        cli.command.run(&Session::new(cli.quiet, cli.no_wait))
    };
    match run() {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
