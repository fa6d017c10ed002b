# terrabake: the two commands a fresh machine needs are `make demo` and
# `make test`; the rest are for developers.
CARGO ?= cargo
BIN := target/release/terrabake
BENCH := target/release/terrabake-bench
DEMO_DEM := data/srtm3_n07w006_geographic_int16.tif
OUT ?= out

.PHONY: all build build-bench demo test test-bindings test-full wheel capi capi-header test-page bake-parts bake-slurm test-slurm fuzz bench-ingest-ooc bench-trace bench-cones bench-horizons bench-horizons-ooc bench-visibility bench-plan time-models bench-cog bench-peers bench-targets bench-reader fixtures fmt lint clean

all: build

build:
	$(CARGO) build --release --locked

## The benchmark harnesses' binary (terrabake-bench, benches/): the product
## never compiles them or their chart library.
build-bench: build
	$(CARGO) build --release --locked -p terrabake-bench --bin terrabake-bench

## Bake the bundled SRTM tile: asset, summary (text and JSON), verification,
## previews with legends, and out/index.html, one page with all of them.
demo: build
	mkdir -p $(OUT)
	$(BIN) bake $(DEMO_DEM) -o $(OUT)/srtm.tbake --recipe pipelines/demo.toml
	$(BIN) info $(OUT)/srtm.tbake > $(OUT)/srtm.summary.txt
	$(BIN) info $(OUT)/srtm.tbake --json > $(OUT)/srtm.summary.json
	$(BIN) verify $(OUT)/srtm.tbake > $(OUT)/srtm.verify.txt
	$(BIN) export $(OUT)/srtm.tbake --layer height --style relief -o $(OUT)/srtm_relief.png
	$(BIN) export $(OUT)/srtm.tbake --layer height --style gray -o $(OUT)/srtm_gray16.png
	$(BIN) render $(OUT)/srtm.tbake --camera 30000,8000,4500 --look-at 55000,60000,500 --fov 60 --sun 290,10 --exaggerate 8 --size 1024x640 --method parametric --stats -o $(OUT)/srtm_view.png > $(OUT)/srtm_view.stats.txt
	$(BIN) export $(OUT)/srtm.tbake --layer horizon -o $(OUT)/srtm_horizon.tif
	$(BIN) export $(OUT)/srtm.tbake --layer svf -o $(OUT)/srtm_svf.png
	$(BIN) render $(OUT)/srtm.tbake --shade sky -o $(OUT)/srtm_sky.png
	$(BIN) render $(OUT)/srtm.tbake --shade sun:250,15 -o $(OUT)/srtm_sun.png
	$(BIN) export $(OUT)/srtm.tbake --layer total_viewshed -o $(OUT)/srtm_total_viewshed.png
	$(BIN) export $(OUT)/srtm.tbake --layer solar_global -o $(OUT)/srtm_solar_global.png
	$(BIN) export $(OUT)/srtm.tbake --layer sun_hours -o $(OUT)/srtm_sun_hours.png
	$(BIN) viewshed $(OUT)/srtm.tbake --observer -5.5,7.5 --crs lonlat --observer-height 10 -o $(OUT)/srtm_viewshed.tif
	$(BIN) check $(OUT)/srtm.tbake --samples 100 --no-record > $(OUT)/srtm.check.txt
	$(BIN) page $(OUT)/srtm.tbake -o $(OUT)/index.html \
	  --picture "$(OUT)/srtm_view.png=Traced through the asset (parametric tracing, shadow rays, sun at 290, 10 degrees, heights x8)" \
	  --picture "$(OUT)/srtm_relief.png=Heights: hypsometric tint and hillshade" \
	  --picture "$(OUT)/srtm_svf.png=Sky-view factor from 32 exact horizon lines" \
	  --picture "$(OUT)/srtm_sky.png=Overcast sky light from the horizons alone (Stewart's radiosity)" \
	  --picture "$(OUT)/srtm_sun.png=Sun at 250, 15 degrees: shadows and sky from the horizons alone" \
	  --picture "$(OUT)/srtm_total_viewshed.png=Total viewshed: area seen within 5 km from 1.7 m above each post, square metres" \
	  --picture "$(OUT)/srtm_solar_global.png=The year's mean daily clear-sky irradiation, kWh/m2: r.sun's model shadowed by the stored horizons" \
	  --picture "$(OUT)/srtm_sun_hours.png=The year's mean daily sun hours: the sun's centre above the horizon and in front of the slope" \
	  --chart "docs/charts/horizons_horizon.svg=Horizon angle error against bake time, every method (make bench-horizons)" \
	  --chart "docs/charts/horizons_svf.svg=Sky-view factor error against bake time (make bench-horizons)" \
	  --chart "docs/charts/viewshed_rviewshed.svg=Observer viewsheds: time against reach beside GRASS r.viewshed, labelled with the agreement (pipelines/compare_grass_viewshed.sh)" \
	  --chart "docs/charts/cones_speed.svg=Parametric tracing: rays per second against cone slices (make bench-cones)" \
	  --chart "docs/charts/cones_bytes.svg=Tracing: rays per second against the bytes a post each tracer reads, every tracer (make bench-cones)" \
	  --chart "docs/charts/trace_scaling_time.svg=Time per ray against DEM size, every tracer (make bench-trace)" \
	  --chart "docs/charts/solar_jacksboro_utm80_f32.svg=Solar: day 172's irradiation error against time, our direction counts beside GRASS r.sun on Jacksboro (pipelines/solar/chart_rsun.sh)" \
	  --chart "docs/charts/solar_vs_rsun_172.png=Our day 172 against r.sun's own shadowing, per cent, on two projected DEMs (pipelines/solar/compare_rsun.sh)" \
	  --text "$(OUT)/srtm_view.stats.txt=The view's tracing statistics" \
	  --text "$(OUT)/srtm.check.txt=terrabake check: the baked horizons, cone planes and tracers against exact references from the heights" \
	  --text "$(OUT)/srtm.verify.txt=terrabake verify"
	@cat $(OUT)/srtm.summary.txt
	@echo
	@echo "page:     $(OUT)/index.html (open it in a browser: every picture, chart and summary below)"
	@echo "asset:    $(OUT)/srtm.tbake"
	@echo "summary:  $(OUT)/srtm.summary.txt ($(OUT)/srtm.summary.json)"
	@echo "previews: $(OUT)/srtm_relief.png $(OUT)/srtm_gray16.png $(OUT)/srtm_view.png"
	@echo "horizons: $(OUT)/srtm_horizon.tif (32 bands, degrees) $(OUT)/srtm_svf.png $(OUT)/srtm_sky.png $(OUT)/srtm_sun.png"
	@echo "solar:    $(OUT)/srtm_solar_global.png $(OUT)/srtm_sun_hours.png (the year's mean day, clear sky)"
	@echo "check:    $(OUT)/srtm.check.txt (achieved horizon error; cones and rays against the brute force)"
	@echo "viewshed: $(OUT)/srtm_total_viewshed.png $(OUT)/srtm_viewshed.tif (from 5.5 W 7.5 N, eye 10 m: band 1 visible, band 2 angle)"

## Every test of the pipeline, the loader crate and the C ABI's crate, in
## the release profile that `make demo` (and `make build`) already built:
## the dependencies are compiled once for both.
test:
	$(CARGO) test --release --locked

## The bindings through their real clients, which CI runs after `make test`:
## the C ABI through gcc, the wgpu shader (lavapipe installed where there is
## no Vulkan driver), the Python wheel in a fresh virtual environment (with
## GDAL, xarray and rioxarray), and GRASS r.sun on exported horizons.
test-bindings: build
	bash pipelines/capi/test.sh target/release/terrabake
	bash pipelines/gpu/test.sh
	bash pipelines/python/test.sh
	bash pipelines/gis/check_grass.sh target/release/terrabake

## The Python package as an abi3 wheel (CPython 3.9 on, manylinux2014)
## and its sdist in target/wheels/: `pip install target/wheels/*.whl` needs
## no Rust. maturin comes from PyPI (pipelines/python/wheel.sh).
wheel:
	bash pipelines/python/wheel.sh

## The C ABI (docs/CAPI.md): target/capi/ gets libterrabake_c.so and .a,
## terrabake.h and the example program, built with the machine's gcc.
capi:
	$(CARGO) build --release --locked -p terrabake-capi
	mkdir -p target/capi
	cp target/release/libterrabake_c.so target/release/libterrabake_c.a capi/include/terrabake.h target/capi/
	gcc -O2 -g -std=c11 -Wall -Wextra -Werror -D_DEFAULT_SOURCE examples/c/sample.c -I capi/include \
	  target/capi/libterrabake_c.a -lpthread -ldl -lm -o target/capi/sample

## Regenerate capi/include/terrabake.h (cbindgen: cargo install cbindgen).
capi-header:
	cbindgen --config capi/cbindgen.toml --crate terrabake-capi --output capi/include/terrabake.h capi

## Every test again with debug assertions and overflow checks
## ([profile.test]: optimised, but checked), and the tracers' full matrices
## (10^6 rays per method and terrain, against 2 x 10^5 in `make test`);
## the benchmark harnesses' tests (terrabake-bench); CI runs it after `make test`.
test-full:
	TERRABAKE_TRACE_RAYS=1000000 $(CARGO) test --locked
	$(CARGO) test --release --locked -p terrabake-bench
	VALGRIND=1 bash pipelines/capi/test.sh target/release/terrabake

## The demo page in a real headless browser (Debian's chromium, installed
## if missing): it loads, every picture shows, the console stays quiet.
test-page: demo
	bash pipelines/page/check.sh $(OUT)/index.html

## Partitioned bakes (docs/SCALE.md). On one box, the parts as make jobs:
##   make bake-parts SRC=dem.tif OUT=dem.tbake RECIPE=pipelines/demo.toml PARTS=8 -j8
## On Slurm: an array job (one task per part) and a dependent assemble job;
## waits, and fails naming the failed parts:
##   make bake-slurm SRC=dem.tif OUT=dem.tbake RECIPE=pipelines/demo.toml PARTS=64
PARTS ?= 4
PART_TARGETS := $(addprefix part-,$(shell seq 0 $$(($(PARTS) - 1))))
bake-parts: build
	@test -n "$(SRC)" -a -n "$(OUT)" -a -n "$(RECIPE)" || { echo "give SRC=, OUT=, RECIPE= (and PARTS=)"; exit 2; }
	$(MAKE) --no-print-directory $(PART_TARGETS)
	$(BIN) assemble $(OUT)
part-%:
	$(BIN) bake $(SRC) -o $(OUT) --recipe $(RECIPE) --parts $(PARTS) --part $* --quiet

bake-slurm: build
	@test -n "$(SRC)" -a -n "$(OUT)" -a -n "$(RECIPE)" || { echo "give SRC=, OUT=, RECIPE= (and PARTS=)"; exit 2; }
	TB=$(BIN) bash pipelines/slurm/bake.sh $(SRC) $(OUT) $(RECIPE) $(PARTS)

## A one-node Slurm cluster on localhost (root; installs slurm-wlm and munge
## if missing): partitioned bakes on it equal one machine's. Not in `make test`.
test-slurm: build
	bash pipelines/slurm/test.sh

## Coverage-guided fuzzing of the reader and of ingest (cargo-fuzz,
## libFuzzer without a sanitizer, on the stable toolchain), FUZZ_SECONDS
## each. `make test` runs the same targets for a fixed number of iterations.
FUZZ_SECONDS ?= 300
fuzz:
	command -v cargo-fuzz >/dev/null || $(CARGO) install cargo-fuzz --locked
	mkdir -p fuzz/corpus/ingest && cp tests/fixtures/tiff/*.tif fuzz/corpus/ingest/
	cd fuzz && RUSTC_BOOTSTRAP=1 $(CARGO) fuzz run --sanitizer none -O reader -- -max_total_time=$(FUZZ_SECONDS)
	cd fuzz && RUSTC_BOOTSTRAP=1 $(CARGO) fuzz run --sanitizer none -O ingest corpus/ingest -- -max_total_time=$(FUZZ_SECONDS) -rss_limit_mb=4096

## Out-of-core ingest of a generated 4 GiB GeoTIFF under a 1 GiB memory limit.
bench-ingest-ooc: build
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_ingest_out_of_core.sh

## Tracing: Table 1 on the SRTM tile, cost by azimuth, scaling with DEM size.
bench-trace: build-bench
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_trace.sh

## Horizons: speed and accuracy on the SRTM tile, time and memory against
## DEM size, the Fourier chart (docs/charts/horizons_fourier.svg), and the
## line sweep against this machine's memory-bandwidth floor.
bench-horizons: build-bench
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_horizons.sh
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_line_floor.sh

## Timonen's tables on the SRTM tile and synthetic terrains, the bounded
## total viewshed, charts docs/charts/visibility_*.svg; then the observer
## viewsheds beside GRASS r.viewshed (installed if missing).
bench-visibility: build-bench
	mkdir -p $(OUT)/bench
	$(BIN) ingest $(DEMO_DEM) -o $(OUT)/bench/srtm.tbake -q
	$(BENCH) visibility $(OUT)/bench/srtm.tbake --crop 1024 --directions 16 --scaling --errors --bounded 5000
	$(BENCH) visibility $(OUT)/bench/srtm.tbake --crop 512 --directions 16 --scaling 128,256,512,1024,2048 --chart docs/charts/visibility
	bash pipelines/compare_grass_viewshed.sh

## Out-of-core line horizons: a 1 GiB DEM in a 512 MiB cgroup (root).
bench-horizons-ooc: build
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_horizons_out_of_core.sh

## Cone planes: bake time against DEM size and slices; speed against bake
## time on the SRTM tile (table and docs/charts/cones_*.svg).
bench-cones: build-bench
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_cones.sh
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_cones_out_of_core.sh

## The planner's charts: plan, bake and check the bundled tile, the held-out
## DEMs and the synthetic terrains at five budgets (docs/charts/planning_*.svg,
## the table in docs/BENCHMARKS.md); then refit its time models.
bench-plan: build-bench
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_plan.sh
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/fit_plan_models.sh

## This machine's time models for the planner (docs/PLANNING.md, "A
## machine's own models"): bake with TERRABAKE_TIME_MODELS=time-models.json.
time-models: build-bench
	BIN=$(BIN) OUT=time-models.json bash pipelines/fit_plan_models.sh

## The peers beside us: HORAYZON, WhiteboxTools, topocalc, RVT, SurtGIS,
## GRASS r.horizon and SAGA installed (Debian packages, a venv from PyPI)
## and run on the same DEM, directions and radius as terrabake; their error
## against our exact reference, time and peak memory (docs/BENCHMARKS.md),
## and their points on docs/charts/horizons_*.svg.
bench-peers: build-bench
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/peers/bench_peers.sh

## Issue #17's speed targets on this machine, each against its target, in
## one run (docs/BENCHMARKS.md, "The speed targets of #17"): the sector
## horizons, the cone planes and parametric tracing measured here; the line
## horizons' ratio to HORAYZON comes from bench-peers.
bench-targets: build-bench
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_targets.sh

## COG export: a 1 GiB height layer inside a 256 MiB memory cgroup,
## deflate/zstd/none, beside GDAL's COG driver (and OLD=binary alternating).
bench-cog: build
	BIN=$(BIN) BENCH=$(BENCH) bash pipelines/bench_cog.sh

## Reader micro-benchmarks (criterion).
bench-reader:
	$(CARGO) bench -p terrabake-bench --bench reader

## Regenerate the GDAL-made TIFF fixtures (needs Debian's python3-gdal).
## The v1 compatibility asset is never regenerated: see tests/fixtures/README.md.
fixtures:
	/usr/bin/python3 tests/fixtures/make_tiff_fixtures.py

fmt:
	$(CARGO) fmt --all

lint:
	$(CARGO) clippy --workspace --all-targets -- -D warnings

clean:
	rm -rf $(OUT)
	$(CARGO) clean
