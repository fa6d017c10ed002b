//! Ctrl-C and a scheduler's SIGTERM: the process removes the temporary
//! files it was writing (never a committed file: an asset stays as its last
//! commit left it), says what it was doing and that running the same
//! command again resumes, and exits with status 130. A command that works
//! in a scratch directory of its own (`plan SRC`, which ingests the DEM
//! there) registers it with [`scratch`]: an interrupt removes it too, and
//! the message does not promise a resume.

use std::path::PathBuf;
use std::sync::Mutex;

/// Scratch directories the process made, removed on an interrupt.
static SCRATCH: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Registers `dir`, a scratch directory of this process that nothing reads
/// after it: an interrupt removes it.
pub fn scratch(dir: PathBuf) {
    SCRATCH.lock().unwrap_or_else(|e| e.into_inner()).push(dir);
}

/// What the process is doing, for the message: a stage and its asset.
static DOING: Mutex<Option<String>> = Mutex::new(None);

/// Says what the process is doing from now on (`None`: nothing to name).
pub(crate) fn doing(what: Option<String>) {
    *DOING.lock().unwrap_or_else(|e| e.into_inner()) = what;
}

/// Says what the process is doing until the value is dropped.
#[derive(Debug)]
#[must_use = "the process is doing it only while this lives"]
pub struct Doing;

impl Doing {
    pub fn now(what: String) -> Self {
        doing(Some(what));
        Self
    }
}

impl Drop for Doing {
    fn drop(&mut self) {
        doing(None);
    }
}

/// Installs the handler (once, at start).
pub fn install() {
    let _ = ctrlc::set_handler(|| {
        let removed = terrabake_format::fsio::remove_temporaries();
        let doing = DOING.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let during = doing.map_or(String::new(), |d| format!(" during {d}"));
        let scratch = std::mem::take(&mut *SCRATCH.lock().unwrap_or_else(|e| e.into_inner()));
        if scratch.is_empty() {
            eprintln!(
                "\ninterrupted{during}: removed {removed} temporary file(s); what was committed is kept, and running the same command again resumes"
            );
        } else {
            for dir in &scratch {
                let _ = std::fs::remove_dir_all(dir);
            }
            eprintln!(
                "\ninterrupted{during}: removed its scratch directory; nothing was kept (run the command again to start over)"
            );
        }
        std::process::exit(130);
    });
}
