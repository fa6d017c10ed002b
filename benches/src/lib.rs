//! The benchmark harnesses behind `terrabake-bench` (`src/main.rs`): what
//! `views`, `cones`, `horizons`, `plan`, `visibility`, `solar` and `points` measure and how they print and chart
//! it (docs/BENCHMARKS.md has the figures and the commands).
//!
//! - [`views`]: the tracers over the sixteen oblique views (Paglieroni and
//!   Petersen's Table 1), by azimuth, and against DEM size.
//! - [`cones`]: the parametric tracer's speed against the cone planes' bake
//!   time, per slice count and encoding.
//! - [`horizons`]: the horizon methods' speed, and their accuracy against a
//!   dense exact reference.
//! - [`peers`]: other tools' horizons and sky-view factors, scored
//!   against the same reference (`make bench-peers`).
//! - [`plan`]: planned bakes, their achieved error and cost against the
//!   budget.
//! - [`solar`]: the solar panel, from the points `r.sun` beside us gives
//!   (pipelines/solar/chart_rsun.sh).
//! - [`points`]: a chart from points a script measured beside a peer (the
//!   viewsheds beside `r.viewshed`).
//! - [`markdown_table`] and [`chart`]: the one table writer and the one
//!   chart writer they all use.

pub mod chart;
pub mod cones;
pub mod horizons;
pub mod peers;
pub mod plan;
pub mod points;
pub mod solar;
pub mod views;
pub mod visibility;

/// A Markdown table: a header row, the separator, then one row per item.
pub fn markdown_table(header: &[&str], rows: impl IntoIterator<Item = Vec<String>>) -> String {
    let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
    let header: Vec<String> = header.iter().map(|h| h.to_string()).collect();
    let mut s = line(&header);
    s += &line(&vec!["---".to_string(); header.len()]);
    for row in rows {
        s += &line(&row);
    }
    s
}

#[cfg(test)]
mod tests {
    #[test]
    fn markdown_tables_have_a_header_a_separator_and_rows() {
        let t = super::markdown_table(&["a", "b"], [vec!["1".into(), "2".into()]]);
        assert_eq!(t, "| a | b |\n| --- | --- |\n| 1 | 2 |\n");
    }
}
