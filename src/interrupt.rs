//! Ctrl-C and a scheduler's SIGTERM: the process removes the temporary
//! files it was writing (never a committed file: an asset stays as its last
//! commit left it), says what it was doing and that running the same
//! command again resumes, and exits with status 130.

use std::sync::Mutex;

/// What the process is doing, for the message: a stage and its asset.
static DOING: Mutex<Option<String>> = Mutex::new(None);

/// Says what the process is doing from now on (`None`: nothing to name).
pub fn doing(what: Option<String>) {
    *DOING.lock().unwrap_or_else(|e| e.into_inner()) = what;
}

/// Installs the handler (once, at start).
pub fn install() {
    let _ = ctrlc::set_handler(|| {
        let removed = terrabake_format::fsio::remove_temporaries();
        let doing = DOING.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let during = doing.map_or(String::new(), |d| format!(" during {d}"));
        eprintln!(
            "\ninterrupted{during}: removed {removed} temporary file(s); what was committed is kept, and running the same command again resumes"
        );
        std::process::exit(130);
    });
}
