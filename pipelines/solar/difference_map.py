"""The maps of terrabake's day against r.sun's, for the demo page.

Reads the signed differences compare_rsun.sh writes (100 (ours - r.sun) /
r.sun of day 172's global irradiation, r.sun with its own shadowing) and
draws them side by side in a diverging ramp, blue where ours is lower,
red where higher, clipped at +-LIMIT per cent, with a legend and each map's
mean and 95th percentile of the absolute difference.

    python difference_map.py OUT.png LIMIT TITLE=FILE.tif [TITLE=FILE.tif ...]
"""

import sys

import numpy as np
import tifffile
from PIL import Image, ImageDraw

SIDE = 420  # pixels across each map
PAD = 16


def ramp(t: np.ndarray) -> np.ndarray:
    """Blue (t = 0) through white (0.5) to red (1): RGB, uint8."""
    blue, white, red = np.array([33, 102, 172]), np.array([247, 247, 247]), np.array([178, 24, 43])
    # 33 steps (a step 1/16 of the limit): few colours, so the PNG stays small.
    t = np.round(np.clip(np.nan_to_num(t, nan=0.5), 0.0, 1.0) * 32) / 32
    t = t[..., None]
    low = blue + (white - blue) * (t / 0.5)
    high = white + (red - white) * ((t - 0.5) / 0.5)
    return np.where(t < 0.5, low, high).astype(np.uint8)


def main() -> None:
    out, limit, maps = sys.argv[1], float(sys.argv[2]), sys.argv[3:]
    panels = []
    for spec in maps:
        title, path = spec.split("=", 1)
        d = tifffile.imread(path).astype(np.float64)
        d[~np.isfinite(d) | (d < -1e30)] = np.nan
        step = max(1, int(np.ceil(max(d.shape) / SIDE)))
        small = d[::step, ::step]
        rgb = ramp((small + limit) / (2 * limit))
        rgb[np.isnan(small)] = (200, 200, 200)
        a = np.abs(d[np.isfinite(d)])
        note = f"mean |diff| {a.mean():.2f} %, p95 {np.percentile(a, 95):.2f} %"
        panels.append((title, note, Image.fromarray(rgb)))
    width = PAD + sum(p[2].width + PAD for p in panels)
    height = PAD + 30 + max(p[2].height for p in panels) + 70
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    x = PAD
    for title, note, panel in panels:
        draw.text((x, PAD), title, fill="black")
        draw.text((x, PAD + 14), note, fill="black")
        img.paste(panel, (x, PAD + 30))
        x += panel.width + PAD
    # The legend: the ramp, its ends and middle.
    bar_y = PAD + 30 + max(p[2].height for p in panels) + 14
    bar_w = min(360, width - 2 * PAD)
    bar = ramp(np.tile(np.linspace(0.0, 1.0, bar_w), (14, 1)))
    img.paste(Image.fromarray(bar), (PAD, bar_y))
    for frac, label in ((0.0, f"-{limit:g} %"), (0.5, "0"), (1.0, f"+{limit:g} %")):
        draw.text((PAD + int(frac * (bar_w - 30)), bar_y + 18), label, fill="black")
    draw.text(
        (PAD + bar_w + 12, bar_y),
        "100 (terrabake - r.sun) / r.sun, day 172 global irradiation;",
        fill="black",
    )
    draw.text(
        (PAD + bar_w + 12, bar_y + 14),
        f"clipped beyond +-{limit:g} %; gray: r.sun's null edge",
        fill="black",
    )
    # Under 256 colours (the ramp's 33, the text's): a palette keeps them all.
    img.convert("P", palette=Image.Palette.ADAPTIVE, colors=256).save(out, optimize=True)


if __name__ == "__main__":
    main()
