//! The demo page (`terrabake page`): one self-contained HTML file with an
//! asset's summary, its previews and the speed/accuracy charts, for a
//! person to open in a browser. Pictures are inlined as data URIs, so the
//! page can be moved, mailed or archived alone; it loads nothing from
//! elsewhere and runs one script, which marks every picture loaded or
//! broken (`data-state` on each `<img>`, and a count in `#status`), so that
//! a headless browser can check the page as a person would see it
//! (`pipelines/page/check.sh`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use base64::Engine as _;

use crate::error::bail;
use crate::stage::session::{Run, Session};

/// `terrabake page`: its arguments.
#[derive(clap::Args, Debug)]
#[command(after_help = "Example (what `make demo` runs):\n  \
terrabake page out/srtm.tbake -o out/index.html \\\n    \
--picture 'out/srtm_view.png=A view traced through the asset' \\\n    \
--chart 'docs/charts/horizons_horizon.svg=Horizon error against bake time'")]
pub struct PageArgs {
    /// The asset the page describes (its summary heads the page).
    pub asset: PathBuf,
    /// The page to write (HTML; its directory is created).
    #[arg(short, long)]
    pub output: PathBuf,
    /// A picture and its caption, FILE=CAPTION (PNG or SVG); in the order given.
    #[arg(long, value_parser = parse_captioned)]
    pub picture: Vec<(PathBuf, String)>,
    /// A chart and its caption, FILE=CAPTION (SVG or PNG); under the pictures.
    #[arg(long, value_parser = parse_captioned)]
    pub chart: Vec<(PathBuf, String)>,
    /// A text file and its heading, FILE=HEADING (a command's output); under the summary.
    #[arg(long, value_parser = parse_captioned)]
    pub text: Vec<(PathBuf, String)>,
}

fn parse_captioned(s: &str) -> Result<(PathBuf, String), String> {
    let (file, caption) = s
        .split_once('=')
        .ok_or_else(|| format!("{s:?}: expected FILE=CAPTION"))?;
    Ok((PathBuf::from(file), caption.to_string()))
}

impl Run for PageArgs {
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let mut texts = vec![(
            "Summary (terrabake info)".to_string(),
            crate::present::report::info(&self.asset, false)?,
        )];
        for (path, heading) in &self.text {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            texts.push((heading.clone(), text));
        }
        let html = page(
            &format!("terrabake: {}", self.asset.display()),
            &texts,
            &self.picture,
            &self.chart,
        )?;
        crate::plumbing::output::write_atomically(&self.output, |file| {
            use std::io::Write;
            Ok(file.write_all(html.as_bytes())?)
        })?;
        s.say(format!("wrote {}", self.output.display()));
        Ok(ExitCode::SUCCESS)
    }
}

/// A file as a data URI, its type from its extension.
fn data_uri(path: &Path) -> Result<String> {
    let mime = match path.extension().and_then(|e| e.to_str()) {
        Some("png") => "image/png",
        Some("svg") => "image/svg+xml",
        _ => bail!("{}: a page shows .png and .svg pictures", path.display()),
    };
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(format!(
        "data:{mime};base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    ))
}

/// Text for HTML: the five characters that mean markup, escaped.
fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&#39;")
}

/// The page's HTML: the pictures, the charts, then each text under its
/// heading.
pub fn page(
    title: &str,
    texts: &[(String, String)],
    pictures: &[(PathBuf, String)],
    charts: &[(PathBuf, String)],
) -> crate::Result<String> {
    let mut html = String::new();
    let _ = write!(
        html,
        r#"<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; padding: 0 1em; color: #222; }}
pre {{ background: #f4f4f4; padding: 1em; overflow-x: auto; font-size: 0.85em; }}
.grid {{ display: grid; grid-template-columns: repeat(auto-fill, minmax(360px, 1fr)); gap: 1.5em; }}
figure {{ margin: 0; }}
.grid.first-wide figure:first-child {{ grid-column: 1 / -1; }}
img {{ width: 100%; height: auto; border: 1px solid #ddd; background: #fff; }}
figure img {{ cursor: zoom-in; }}
#viewer {{ position: fixed; inset: 0; background: rgba(0, 0, 0, 0.8); display: flex; align-items: center; justify-content: center; cursor: zoom-out; z-index: 10; }}
#viewer[hidden] {{ display: none; }}
#viewer img {{ width: 96vw; height: 96vh; object-fit: contain; border: none; background: transparent; }}
#viewer img[src^="data:image/svg"] {{ background: #fff; }}
figcaption {{ font-size: 0.9em; margin-top: 0.3em; }}
#status {{ color: #666; font-size: 0.8em; }}
</style>
</head>
<body>
<h1>{title}</h1>
<p id="status">loading pictures</p>
"#,
        title = escape(title)
    );
    // The first picture (the demo's view) across the page.
    let mut section = |heading: &str, class: &str, items: &[(PathBuf, String)]| -> Result<()> {
        if items.is_empty() {
            return Ok(());
        }
        let _ = writeln!(html, "<h2>{heading}</h2>\n<div class=\"{class}\">");
        for (path, caption) in items {
            let _ = writeln!(
                html,
                "<figure><img src=\"{}\" alt=\"{caption}\"><figcaption>{caption} <small>({file})</small></figcaption></figure>",
                data_uri(path)?,
                caption = escape(caption),
                file = escape(&path.display().to_string())
            );
        }
        html.push_str("</div>\n");
        Ok(())
    };
    section("Pictures", "grid first-wide", pictures)?;
    section("Speed and accuracy", "grid", charts)?;
    for (heading, text) in texts {
        let _ = writeln!(
            html,
            "<h2>{}</h2>\n<pre>{}</pre>",
            escape(heading),
            escape(text)
        );
    }
    html.push_str(
        r#"<script>
// A click on a picture or a chart opens it over the page as large as the
// window allows; a click or Escape closes it. `#view-N` in the address
// opens the Nth at load (the headless check uses it).
function view(img) {
  let viewer = document.getElementById("viewer");
  if (!viewer) {
    viewer = document.createElement("div");
    viewer.id = "viewer";
    viewer.appendChild(document.createElement("img"));
    viewer.addEventListener("click", () => { viewer.hidden = true; });
    document.body.appendChild(viewer);
  }
  viewer.firstChild.src = img.src;
  viewer.firstChild.alt = img.alt;
  viewer.dataset.shows = img.alt;
  viewer.hidden = false;
}
document.addEventListener("keydown", (e) => {
  const viewer = document.getElementById("viewer");
  if (e.key === "Escape" && viewer) viewer.hidden = true;
});
// Marks each picture loaded or broken, and counts them, for a person and
// for the headless check (pipelines/page/check.sh).
window.addEventListener("load", () => {
  const images = [...document.images];
  let loaded = 0;
  for (const img of images) {
    const ok = img.complete && img.naturalWidth > 0;
    img.dataset.state = ok ? "loaded" : "broken";
    loaded += ok;
    img.addEventListener("click", () => view(img));
  }
  document.getElementById("status").textContent = `${loaded} of ${images.length} pictures loaded`;
  const asked = location.hash.match(/^#view-(\d+)$/);
  if (asked && images[asked[1] - 1]) view(images[asked[1] - 1]);
});
</script>
</body>
</html>
"#,
    );
    Ok(html)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_inlines_every_picture_and_escapes_text() {
        let dir = tempfile::tempdir().unwrap();
        let svg = dir.path().join("chart.svg");
        std::fs::write(&svg, "<svg xmlns='http://www.w3.org/2000/svg'/>").unwrap();
        let html = page(
            "a <title>",
            &[("Summary".into(), "size 3 & 4".into())],
            &[(svg.clone(), "a \"chart\"".into())],
            &[(svg.clone(), "again".into())],
        )
        .unwrap();
        assert_eq!(
            html.matches("<img src=\"data:image/svg+xml;base64,")
                .count(),
            2
        );
        assert!(html.contains("a &lt;title&gt;") && html.contains("size 3 &amp; 4"));
        assert!(html.contains("alt=\"a &quot;chart&quot;\""));
        // Nothing is fetched from elsewhere.
        assert!(!html.contains("src=\"http") && !html.contains("href="));
        let missing = page("t", &[], &[(dir.path().join("none.png"), "c".into())], &[]);
        assert!(format!("{:#}", missing.unwrap_err()).contains("none.png"));
        let tiff = page("t", &[], &[(dir.path().join("x.tif"), "c".into())], &[]);
        assert!(format!("{:#}", tiff.unwrap_err()).contains("x.tif"));
    }
}
