# The numpy call against the CLI stage (docs/BENCHMARKS.md): three rounds,
# alternating. Usage: python overhead.py TERRABAKE_BIN ASSET (an ingested
# asset; the script rewrites its horizons).
import json, subprocess, sys, time
import numpy as np
import terrabake
a = terrabake.open(sys.argv[2])
z = a.read("height")[0]
m = json.loads(a.manifest_json())
cs = (m["cell_size"]["dx"], m["cell_size"]["dy"])
for r in range(3):
    out = subprocess.run([sys.argv[1], "horizons", sys.argv[2], "--sectors", "16", "--encoding", "f32", "--force", "--json", "-q"], capture_output=True, text=True).stdout
    rec = json.loads(out)
    stages = rec if isinstance(rec, list) else [rec]
    cli = {s["stage"]: s["seconds"] for s in stages}
    t0 = time.perf_counter(); h, az = terrabake.horizons(z, cs, sectors=16, curvature=True); t1 = time.perf_counter()
    s = terrabake.sky_view_factor(z, cs, sectors=16, curvature=True); t2 = time.perf_counter()
    same = np.array_equal(h, terrabake.open(sys.argv[2]).read("horizon"), equal_nan=True)
    print(f"round {r+1}: CLI stage horizons {cli.get('horizons'):.3f} s, sky {cli.get('sky', float('nan')):.3f} s; python horizons {t1-t0:.3f} s, sky_view_factor {t2-t1:.3f} s; equal {same}")
