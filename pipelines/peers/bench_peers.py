"""`make bench-peers`: every peer beside terrabake, in one run.

    python3 bench_peers.py --bin target/release/terrabake --venv target/peers-venv \
        --dem DEM.tif --work DIR [--directions 16] [--crop 256] [--limit 600] [--tolerance DEG] \
        [--knobs 8,16,32,64] [--radii 16,64] [--hori-acc 1,4]

bench_peers.sh installs the peers, then calls this. For each peer: its
computation on the centred CROP x CROP crop of the DEM (outputs converted to
our conventions by run_peer.py, or here for GRASS and SAGA, then scored by
`terrabake-bench horizons --peers`), and its whole process on the whole DEM
under /usr/bin/time (wall seconds, peak RSS), stopped at --limit seconds.
On the crop each peer also runs at every direction count of --knobs, and
GRASS and SAGA at the search radii of --radii, HORAYZON at the hori_acc
of --hori-acc: each knob one curve per peer on the charts, every point
labelled with its setting.
Our own whole-DEM stage is timed the same way, before and after the peers.
Writes DIR/peers.json (benches/src/peers.rs reads it). Standard library only:
it runs under the system Python, the peers under the venv's.
"""

import argparse
import json
import math
import os
import shutil
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
PYTHON_PEERS = {
    # run_peer.py's name for it: the name in the tables.
    "whitebox_workflows": "WhiteboxTools (whitebox-workflows) horizon_angle",
    "topocalc": "topocalc horizon",
    "surtgis": "SurtGIS horizon_angle_map",
    "rvt": "RVT sky_view_factor",
    "horayzon": "HORAYZON horizon_gridded",
}


def timed(label, cmd, work, limit, tries=1, **kw):
    """Runs cmd under /usr/bin/time and timeout, again (up to `tries` runs)
    while it hits the limit: (a WholeRun or None, the reason it failed or
    None, how many runs were stopped at the limit and run again)."""
    out = os.path.join(work, "time.txt")
    # timeout inside time: it signals the peer itself, not time (which
    # would leave the peer running on, and timing the next).
    full = ["/usr/bin/time", "-f", "%e %M", "-o", out, "timeout", "-k", "5", str(limit)] + cmd
    for attempt in range(tries):
        p = subprocess.run(full, capture_output=True, text=True, **kw)
        if p.returncode != 124:
            break
    stops = attempt
    if p.returncode == 124:
        return {"label": label, "seconds": float(limit), "peak_mib": None, "timed_out": True}, None, stops
    if p.returncode != 0:
        tail = (p.stderr or p.stdout).strip().splitlines()[-3:]
        return None, f"exit {p.returncode}: {' / '.join(tail)}", stops
    with open(out) as f:
        secs, kb = f.read().split()[-2:]
    return {"label": label, "seconds": float(secs), "peak_mib": int(kb) / 1024}, None, stops


def whole_fields(run, err):
    """A peer entry's fields for its whole-DEM run: the run, or a note that it failed."""
    return ({"whole": run}, []) if run else ({}, [f"the whole DEM failed: {err}"])


def fresh_dir(path):
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)
    return path


def raster_shape(path):
    info = json.loads(subprocess.check_output(["gdalinfo", "-json", path]))
    cols, rows = info["size"]
    gt = info["geoTransform"]
    return rows, cols, abs(gt[1]), abs(gt[5])


def to_raw(src, dst):
    """Any GDAL raster to raw little-endian float32, north up."""
    subprocess.run(["gdal_translate", "-q", "-of", "ENVI", "-ot", "Float32", src, dst], check=True)


def grass_script(directions, radius_m, outdir):
    """r.horizon in a temporary GRASS location: the crop's horizons, compass order."""
    step = 360.0 / directions
    return f"""set -euo pipefail
r.in.gdal --q input="$DEM" output=dem
g.region raster=dem
t0=$(date +%s.%N)
r.horizon -d --q elevation=dem step={step} maxdistance={radius_m} output=hor
t1=$(date +%s.%N)
echo "$t1 - $t0" | bc > "{outdir}/seconds"
if [ -n "${{EXPORT:-}}" ]; then
  for m in $(g.list raster pattern='hor_*'); do
    r.out.gdal --q -c input=$m output="{outdir}/$m.tif" type=Float32 >/dev/null
  done
fi
"""


def grass_output(directions, outdir):
    """GRASS names each map by its angle counter-clockwise from east, with
    as many decimals as the step needs (hor_011_25): to compass, ascending."""
    bands = []
    for name in os.listdir(outdir):
        if name.startswith("hor_") and name.endswith(".tif"):
            whole, frac = name[4:-4].split("_")
            ccw = int(whole) + int(frac) / 10 ** len(frac)
            bands.append(((90.0 - ccw) % 360.0, os.path.join(outdir, name)))
    assert len(bands) == directions, f"{outdir}: {len(bands)} maps, expected {directions}"
    return sorted(bands)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", required=True)
    ap.add_argument("--venv", required=True)
    ap.add_argument("--dem", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--directions", type=int, default=16)
    ap.add_argument("--crop", type=int, default=256)
    ap.add_argument("--limit", type=int, default=600)
    ap.add_argument("--missing", action="append", default=[], help="PEER=REASON: a peer that could not be installed")
    ap.add_argument("--tolerance", type=float, default=None,
                    help="also time our horizons stage with its line directions this far (degrees) from nominal")
    ap.add_argument("--knobs", default="8,16,32,64", type=lambda v: [int(k) for k in v.split(",") if k],
                    help="direction counts every peer also runs on the crop (a curve each on the charts)")
    ap.add_argument("--radii", default="16,64", type=lambda v: [int(k) for k in v.split(",") if k],
                    help="search radii (cells) GRASS and SAGA also run on the crop at --directions")
    ap.add_argument("--hori-acc", default="1,4", type=lambda v: [float(k) for k in v.split(",") if k],
                    help="HORAYZON's hori_acc (degrees; its default 0.25) also run on the crop at --directions")
    ap.add_argument("--only", default="", help="comma-separated peers to run (horayzon, grass, saga, topocalc, ...; default: all)")
    a = ap.parse_args()
    work = os.path.abspath(a.work)
    os.makedirs(work, exist_ok=True)
    K = a.directions
    rows, cols, dx, dy = raster_shape(a.dem)
    assert abs(dx - dy) < 1e-9 * dx, f"{a.dem}: the peers want square cells, not {dx} x {dy}"
    side = min(a.crop, rows, cols)
    x0, y0 = (cols - side) // 2, (rows - side) // 2
    crop_tif, crop_bin = os.path.join(work, "crop.tif"), os.path.join(work, "crop.bin")
    whole_bin = os.path.join(work, "whole.bin")
    subprocess.run(["gdal_translate", "-q", "-srcwin", str(x0), str(y0), str(side), str(side), a.dem, crop_tif], check=True)
    to_raw(crop_tif, crop_bin)
    to_raw(a.dem, whole_bin)
    radius = {"crop": math.ceil(math.hypot(side, side)), "whole": math.ceil(math.hypot(rows, cols))}
    py = os.path.join(a.venv, "bin", "python")
    peers = []

    def log(msg):
        print(f"bench-peers: {msg}", file=sys.stderr, flush=True)

    # Ours, the whole stage on the whole DEM (ingest timed apart).
    asset = os.path.join(work, "whole.tbake")
    ingest, err, _ = timed("terrabake ingest", [a.bin, "ingest", a.dem, "-o", asset, "-q"], work, a.limit)
    assert ingest, err

    # Three processes of ours, each timed as a peer is: the whole command
    # (the horizons stage, then the sky stage's svf, openness and edge
    # layers), the horizons stage alone (what the peers compute: horizons,
    # no svf), and with --tolerance the stage alone with its directions
    # that far from nominal (what it costs in accuracy, terrabake-bench horizons's
    # "line within" rows say).
    variants = [(f"terrabake horizons, line, {K}", []),
                (f"terrabake horizons --no-sky, line, {K}", ["--no-sky"])]
    if a.tolerance:
        variants.append((f"terrabake horizons --no-sky --direction-tolerance {a.tolerance:g}, line, {K}",
                         ["--no-sky", "--direction-tolerance", f"{a.tolerance:g}"]))
    our_runs = {label: [] for label, _ in variants}

    def ours():
        for label, extra in variants:
            cmd = [a.bin, "horizons", asset, "--method", "line", "--sectors", str(K), "--force", "-q"] + extra
            run, err, _ = timed(label, cmd, work, a.limit)
            assert run, err
            our_runs[label].append(run)

    ours()

    # Each peer runs once more on the crop at every other setting of its
    # accuracy knobs: the direction counts of --knobs for all, and for
    # some a second knob at --directions (--radii, --hori-acc), each a
    # curve of its own on the charts. The whole DEM runs at --directions only.
    counts = [k for k in a.knobs if k != K]
    by_radius = lambda peer: f"{peer}, by search radius ({K} directions)"

    # The Python peers.
    missing = dict(m.split("=", 1) for m in a.missing)
    only = {p for p in a.only.split(",") if p}
    unknown = only - set(PYTHON_PEERS) - {"grass", "saga"}
    assert not unknown, f"--only: no peer named {sorted(unknown)}"
    wanted = lambda peer: not only or peer in only
    for module, name in PYTHON_PEERS.items():
        if not wanted(module):
            continue
        if module in missing:
            peers.append({"name": name, "missing": missing[module]})
            continue
        # HORAYZON's search hangs on some runs and not on others (the same
        # input): its search downwards ends only when a ray hits, and on
        # the UTM tile the steepest ray down from one post (column 1, row
        # 599; its second azimuth) misses the surface in some runs and hits
        # it in others, with the lowest elevation at -90 deg and at -89 deg
        # alike (gdb on the hung runs; Embree builds its tree on several
        # threads). So it gets six tries, each stopped long before the
        # limit: at 60 s on the crop (a second or two when it ends), and on
        # the whole DEM at five times its crop run scaled to the whole DEM
        # (at least 60 s); the reruns are reported.
        hangs = module == "horayzon"
        tries = 6 if hangs else 1
        crop_limit = min(a.limit, 60) if hangs else a.limit
        cmd = [py, os.path.join(HERE, "run_peer.py"), module]

        def crop_run(k, settings, tag, tries=tries, crop_limit=crop_limit):
            """The peer on the crop with k directions and `settings`: (its
            result.json and its folder, relative to work; or None, why)."""
            out = os.path.join(work, module + tag)
            shutil.rmtree(out, ignore_errors=True)
            log(f"{name}: the crop, {k} directions {json.dumps(settings) if settings else ''}")
            run, err, stops = timed(name, cmd + [crop_tif, crop_bin, str(side), str(side), str(dx), str(k), out,
                                                 json.dumps(settings)], work, crop_limit, tries)
            if run is None or run.get("timed_out"):
                return None, "failed on the crop: " + (err or f"no end in {tries} runs of {crop_limit} s")
            with open(os.path.join(out, "result.json")) as f:
                r = json.load(f)
            r["stops"] = stops
            return (r, module + tag), None

        def outputs(series, knob, r, folder, extra):
            """The peer's entries (horizons, its own svf) for one crop run."""
            found = []
            own = lambda: json.loads(json.dumps(extra))  # each entry its own notes
            if "horizons" in r:
                found.append({"name": series, "knob": knob, "version": r["version"], "crop_seconds": r["seconds"],
                              "azimuths_deg": r["azimuths_deg"], "horizons": os.path.join(folder, r["horizons"]),
                              **own()})
            if "svf" in r:
                svf_name = {"topocalc": "topocalc viewf", "rvt": name}[module]
                definition = {"topocalc": "slope_aware", "rvt": "zaksek"}[module]
                found.append({"name": svf_name + series[len(name):], "knob": knob, "version": r["version"],
                              "crop_seconds": r.get("viewf_seconds", r["seconds"]),
                              "svf": os.path.join(folder, r["svf"]), "svf_definition": definition, **own()})
            return found

        main, err = crop_run(K, {}, "")
        if main is None:
            peers.append({"name": name, "missing": err})
            continue
        r, folder = main
        limit = a.limit
        if hangs:
            scaled = 5 * r["seconds"] * (rows * cols) / (side * side)
            limit = min(a.limit, max(60, math.ceil(scaled)))
        log(f"{name}: the whole DEM (limit {limit} s)")
        whole_out = os.path.join(work, module + "_whole")
        w, err, whole_stops = timed(name, cmd + [a.dem, whole_bin, str(rows), str(cols), str(dx), str(K), whole_out],
                                    work, limit, tries)
        shutil.rmtree(whole_out, ignore_errors=True)
        notes = list(r["notes"])
        if r["stops"] or whole_stops:
            notes.append(f"runs stopped and run again: {r['stops']} on the crop (at {crop_limit} s), "
                         f"{whole_stops} on the whole DEM (at {limit} s)")
        # The whole-DEM run goes with the peer's first output.
        first, failed = whole_fields(w, err)
        found = outputs(name, f"K={K}", r, folder, {"notes": notes + failed})
        found[0].update(first)
        if module == "topocalc" and len(found) > 1:
            found[1]["notes"] = [f"viewf: Dozier and Frew's slope-aware svf, nangles = K; the whole-DEM row "
                                 "(topocalc horizon) is horizon and viewf together"]
        peers.extend(found)
        knobs = [(name, f"K={k}", k, {}, f"_k{k}") for k in counts]
        if module == "horayzon":
            knobs += [(f"{name}, by hori_acc ({K} directions)", f"{acc:g} deg", K, {"hori_acc": acc}, f"_acc{acc:g}")
                      for acc in a.hori_acc]
        for series, knob, k, settings, tag in knobs:
            # Fewer tries for a curve's other points (a hung HORAYZON run
            # costs its whole limit).
            run, err = crop_run(k, settings, tag, min(tries, 3), min(crop_limit, 30) if hangs else crop_limit)
            if run is None:
                log(f"{name}: {knob}: {err}")
                found[0]["notes"].append(f"{series[len(name):].strip(', ') or 'curve'} point {knob} left out: {err}")
                continue
            peers.extend(outputs(series, knob, *run, {}))

    # GRASS r.horizon.
    if not wanted("grass"):
        pass
    elif "grass" in missing or not shutil.which("grass"):
        peers.append({"name": "GRASS r.horizon", "missing": missing.get("grass", "grass not on PATH")})
    else:
        version = subprocess.run(["grass", "--version"], capture_output=True, text=True)
        version = (version.stdout + version.stderr).split("GRASS GIS ")[1].split()[0]

        def grass(which, tif, k, radius_cells, tag=""):
            """r.horizon on the crop (exported, and its timing read) or the whole DEM."""
            out = fresh_dir(os.path.join(work, "grass" + tag))
            log(f"GRASS r.horizon: the {which}, {k} directions, {radius_cells} cells")
            script = os.path.join(work, f"grass_{which}.sh")
            with open(script, "w") as f:
                f.write(grass_script(k, radius_cells * dx, out))
            env = dict(os.environ, DEM=tif, EXPORT="1" if which == "crop" else "")
            run, err = timed("GRASS r.horizon", ["grass", "--tmp-location", tif, "--exec", "bash", script],
                             work, a.limit, env=env)[:2]
            if which == "whole":
                return run, err
            assert run, err
            with open(os.path.join(out, "seconds")) as f:
                crop_seconds = float(f.read())
            bands = grass_output(k, out)
            with open(os.path.join(out, "horizons.f32"), "wb") as dst:
                for _, path in bands:
                    to_raw(path, path + ".bin")
                    with open(path + ".bin", "rb") as src:
                        dst.write(src.read())
            return {"version": version, "crop_seconds": crop_seconds, "azimuths_deg": [az for az, _ in bands],
                    "horizons": f"grass{tag}/horizons.f32"}

        crop = grass("crop", crop_tif, K, radius["crop"])
        whole, failed = whole_fields(*grass("whole", a.dem, K, radius["whole"], "_whole"))
        peers.append({
            "name": "GRASS r.horizon", "knob": f"K={K}", **crop, **whole,
            "notes": ["-d (degrees); map angles counter-clockwise from east, compass = 90 - angle",
                      "the whole process includes GRASS's start, the import and the export"] + failed,
        })
        for k in counts:
            peers.append({"name": "GRASS r.horizon", "knob": f"K={k}", **grass("crop", crop_tif, k, radius["crop"], f"_k{k}")})
        for r in a.radii:
            peers.append({"name": by_radius("GRASS r.horizon"), "knob": f"{r} cells",
                          **grass("crop", crop_tif, K, r, f"_r{r}")})

    # SAGA's Sky View Factor (ta_lighting 3): the slope-aware svf.
    if not wanted("saga"):
        pass
    elif "saga" in missing or not shutil.which("saga_cmd"):
        peers.append({"name": "SAGA Sky View Factor", "missing": missing.get("saga", "saga_cmd not on PATH")})
    else:
        version = subprocess.run(["saga_cmd", "--version"], capture_output=True, text=True).stdout.split("SAGA Version:")[1].split()[0]
        out = fresh_dir(os.path.join(work, "saga"))

        def saga(which, tif, k, radius_cells, tag=""):
            log(f"SAGA Sky View Factor: the {which}, {k} sectors, {radius_cells} cells")
            cmd = ["saga_cmd", "ta_lighting", "3", "-DEM", tif, "-SVF", os.path.join(out, f"svf_{which}{tag}.sdat"),
                   "-VISIBLE", os.path.join(out, f"visible_{which}{tag}.sdat"), "-RADIUS", str(radius_cells * dx),
                   "-NDIRS", str(k), "-METHOD", "0"]
            run, err = timed("SAGA Sky View Factor", cmd, work, a.limit)[:2]
            if which == "whole":
                return run, err
            assert run, err
            to_raw(os.path.join(out, f"svf_crop{tag}.sdat"), os.path.join(out, f"svf{tag}.f32"))
            return {"version": version, "crop_seconds": run["seconds"], "svf": f"saga/svf{tag}.f32",
                    "svf_definition": "slope_aware"}

        crop = saga("crop", crop_tif, K, radius["crop"])
        whole, failed = whole_fields(*saga("whole", a.dem, K, radius["whole"]))
        peers.append({
            "name": "SAGA Sky View Factor", "knob": f"K={K}", **crop, **whole,
            "notes": ["-METHOD 0 ('cell size'); its crop time is the whole saga_cmd process (it reports no timing)",
                      "its svf is the slope-aware one; it floors horizons at 0"] + failed,
        })
        for k in counts:
            peers.append({"name": "SAGA Sky View Factor", "knob": f"K={k}", **saga("crop", crop_tif, k, radius["crop"], f"_k{k}")})
        for r in a.radii:
            peers.append({"name": by_radius("SAGA Sky View Factor"), "knob": f"{r} cells",
                          **saga("crop", crop_tif, K, r, f"_r{r}")})

    ours()
    ours()
    stages = []
    for label, runs in our_runs.items():
        median = statistics.median(r["seconds"] for r in runs)
        stage = dict(min(runs, key=lambda r: abs(r["seconds"] - median)), ratio=True)
        stage["notes"] = [f"median of {len(runs)} runs, one before the peers: " + ", ".join(f"{r['seconds']:.2f} s" for r in runs)]
        stages.append(stage)
    stage = stages[0]
    both = {"label": "terrabake ingest + horizons", "seconds": ingest["seconds"] + stage["seconds"],
            "peak_mib": max(ingest["peak_mib"], stage["peak_mib"])}
    manifest = {"dem": os.path.basename(a.dem) + f" ({cols} x {rows}, {dx:g} m)", "crop": side,
                "directions": K, "peers": peers, "ours": stages + [both]}
    with open(os.path.join(work, "peers.json"), "w") as f:
        json.dump(manifest, f, indent=1, allow_nan=False)
    log(f"wrote {os.path.join(work, 'peers.json')}")


if __name__ == "__main__":
    main()
