//! Progress bars on stderr, drawn only when stderr is a terminal and the
//! user did not ask for `--quiet`.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle};
use std::io::IsTerminal;

#[derive(Debug, Clone, Copy)]
pub struct Progress {
    pub enabled: bool,
}

impl Progress {
    pub fn new(quiet: bool) -> Self {
        Self {
            enabled: !quiet && std::io::stderr().is_terminal(),
        }
    }
    pub fn hidden() -> Self {
        Self { enabled: false }
    }

    /// A bar of `len` units labelled `what`, or a hidden one.
    pub fn bar(&self, len: u64, what: &str, unit: &str) -> ProgressBar {
        if !self.enabled {
            return ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::hidden());
        }
        let bar = ProgressBar::new(len);
        let template =
            format!("{{prefix:>10}} [{{bar:40}}] {{pos}}/{{len}} {unit} ({{rate}}, {{eta}} left)");
        let unit = unit.to_string();
        bar.set_style(
            ProgressStyle::with_template(&template)
                .expect("static template")
                .with_key(
                    "rate",
                    move |state: &ProgressState, w: &mut dyn std::fmt::Write| {
                        let _ = write!(w, "{} {unit}/s", human_rate(state.per_sec()));
                    },
                )
                .progress_chars("=> "),
        );
        bar.set_prefix(what.to_string());
        bar
    }
}

/// A rate as people read it: whole numbers from 10 up (`434`, not
/// `434.4949`), one decimal below.
pub(crate) fn human_rate(per_sec: f64) -> String {
    if per_sec >= 10.0 {
        format!("{per_sec:.0}")
    } else {
        format!("{per_sec:.1}")
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn rates_are_rounded_for_people() {
        assert_eq!(super::human_rate(434.4949), "434");
        assert_eq!(super::human_rate(12.5), "12");
        assert_eq!(super::human_rate(2.345), "2.3");
        assert_eq!(super::human_rate(0.0), "0.0");
    }
}
