"""How many of a line sweep's crossings could never be a horizon point.

A crossing inside a step (between two posts of one line) that lies below
the chord of its two neighbours on the profile is popped by the next
vertex in every sweep and never touches a tangent: the surface folds
into a valley there. This counts, for the grid steps of the 16 default
directions on an asset's height layer, the share of such crossings, how
often all lanes of one vector (neighbouring lines, which the SIMD sweep
steps in lockstep) hold one at the same crossing, and what a sweep that
pushed each lane's other crossings only (packed per lane) would push:
the most of any lane's, per step of eight or sixteen lines.

    target/python-venv/bin/python pipelines/line_valley_crossings.py ASSET

(`make test` makes the venv; its figures, 2026-11-27, are in `git log -p docs/BENCHMARKS.md`, "Valley crossings and a pyramid search".)
The profile's heights are the format's surface: linear along grid edges
and along each cell's SW-NE diagonal. Curvature is left out; a margin of
1 mm keeps a crossing counted only where it is clearly below the chord.
"""
import sys

import numpy as np
import terrabake

STEPS = [(2, 5), (2, -5), (5, 2), (5, -2), (1, 1), (1, -1), (0, 1)]


def profile(z, a, b):
    """Fractions of the step and the heights there, for every post P with
    P + (a, b) on the grid: (s, heights[len(s), rows, cols])."""
    h, w = z.shape
    cuts = {k / abs(a) for k in range(1, abs(a))}
    cuts |= {k / abs(b) for k in range(1, abs(b))}
    if a + b:
        cuts |= {k / abs(a + b) for k in range(1, abs(a + b))}
    s = [0.0] + sorted(cuts) + [1.0]
    rows = np.arange(max(0, -b), h - max(0, b))
    cols = np.arange(max(0, -a), w - max(0, a))
    r, c = np.meshgrid(rows, cols, indexing="ij")
    heights = []
    for f in s:
        x, y = c + a * f, r + b * f
        xi, yi = np.floor(x + 1e-12).astype(int), np.floor(y + 1e-12).astype(int)
        fx, fy = x - xi, y - yi
        x1, y1 = np.minimum(xi + 1, w - 1), np.minimum(yi + 1, h - 1)
        if f in (0.0, 1.0):
            v = z[yi, xi]
        elif np.all(fx < 1e-9):  # a vertical grid line
            v = (1 - fy) * z[yi, xi] + fy * z[y1, xi]
        elif np.all(fy < 1e-9):  # a horizontal one
            v = (1 - fx) * z[yi, xi] + fx * z[yi, x1]
        else:  # the cell's SW-NE diagonal, from (xi, yi + 1) to (xi + 1, yi)
            v = fy * z[y1, xi] + fx * z[yi, x1]
        heights.append(v)
    return np.array(s), np.array(heights)


def main(asset):
    z = terrabake.open(asset).read("height")[0].astype(np.float64)
    print("| step | crossings a step | in a valley | all 8 lanes | all 16 lanes | packed pushes, 8 lanes | packed, 16 |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for a, b in STEPS:
        s, v = profile(z, a, b)
        n = len(s) - 2
        if n == 0:
            print(f"| ({a}, {b}) | 0 | - | - | - | 1.00 | 1.00 |")
            continue
        s3 = s[:, None, None]
        chord = v[:-2] + (v[2:] - v[:-2]) * (s3[1:-1] - s3[:-2]) / (s3[2:] - s3[:-2])
        valley = v[1:-1] < chord - 1e-3
        cells = []
        for lanes in (8, 16):
            cut = valley.shape[2] // lanes * lanes
            vv = valley[:, :, :cut].reshape(n, valley.shape[1], cut // lanes, lanes)
            # Pushes a step: the post and the crossings not in a valley.
            kept = (n - vv.sum(axis=0)) + 1
            cells.append((vv.all(axis=3).mean(), kept.max(axis=2).mean() / (n + 1)))
        print(
            f"| ({a}, {b}) | {n} | {valley.mean():.3f} | {cells[0][0]:.3f} | {cells[1][0]:.3f} "
            f"| {cells[0][1]:.2f} | {cells[1][1]:.2f} |"
        )


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
