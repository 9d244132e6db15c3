# q3gltf: Quake III maps to glTF 2.0.
#
#   make                 build, convert the bundled sample to out/sample.gltf, relight it to
#                        out/sample.relit.gltf (+ .report.json, .curve.png)
#   make MAP=oa_dm1      fetch OpenArena (cached), convert that map and relight it likewise
#   make maps            convert every map of the game data to out/maps/*.glb (use -j)
#   make test            the whole test suite (Rust and Python/Node checkers, Blender)
#   make test-blender    the Blender round trip (bpy==5.0.1 in .venv-blender, headless)
#   make render          relit oa_dm1, oacmpdm4, oacmpctf1 (RENDER_MAPS) rendered in Blender
#                        beside the game's own frames (OpenArena on ioquake3 under Xvfb) from
#                        three spawn points each: out/render/table.md, side_by_side/*.png
#   make bench           conversion speed table (out/bench/convert.md), `make -j2 maps` time,
#                        relight of the sample and oa_dm1 (out/bench/relight.md), bake of
#                        their relit scenes (out/bench/bake.md), relight's time per stage
#                        against lights and rows (out/bench/scaling.{md,csv,svg}), and
#                        ours against the thesis's method (out/bench/thesis.{md,csv,svg};
#                        THESIS_BENCH_FLAGS, e.g. --backends cpu,wgpu on a GPU machine)
#   make bench-quick     the scaling and thesis benchmarks on the bundled sample (CI runs it)
#   make sample          regenerate the bundled sample from samples/src (committed)
#   make fuzz            build the cargo-fuzz targets (fuzz/), seed them from the sample and
#                        OpenArena, run each for FUZZ_SECONDS (default 60); see docs/limits.md
#
# Variables: MAP, GAME_DIR (defaults to the fetched OpenArena baseoa), CONVERT_FLAGS,
# RELIGHT_FLAGS, FUZZ_SECONDS.

CARGO      ?= cargo
BIN        := target/release/q3gltf
OUT        := out
VENV       := .venv
PYTHON     ?= python3
CONVERT_FLAGS ?= --entity-lights
RELIGHT_FLAGS ?=
FETCH      := samples/fetch-openarena.sh
BLENDER_VENV := .venv-blender
SAMPLE_BSP := samples/sample/maps/sample.bsp
FUZZ_SECONDS ?= 60

.PHONY: all build sample test test-rust test-python python-deps node-deps maps bench bench-quick clean data fuzz
.PHONY: test-blender blender-deps render
.DELETE_ON_ERROR:

ifeq ($(MAP),)
all: $(OUT)/sample.relit.gltf
else
MAPNAME := $(notdir $(MAP:.bsp=))
all: build
	@mkdir -p $(OUT)
	$(BIN) convert $(MAP) --game-dir "$$(if [ -n '$(GAME_DIR)' ]; then echo '$(GAME_DIR)'; else bash $(FETCH); fi)" $(CONVERT_FLAGS) -o $(OUT)/$(MAPNAME).gltf
	$(BIN) relight $(OUT)/$(MAPNAME).gltf -o $(OUT)/$(MAPNAME).relit.gltf --report $(OUT)/$(MAPNAME).report.json --plot $(OUT)/$(MAPNAME).curve.png $(RELIGHT_FLAGS)
endif

build:
	$(CARGO) build --release --workspace

$(OUT)/sample.gltf: build
	@mkdir -p $(OUT)
	$(BIN) convert $(SAMPLE_BSP) $(CONVERT_FLAGS) -o $@

$(OUT)/sample.relit.gltf: $(OUT)/sample.gltf
	$(BIN) relight $< -o $@ --report $(OUT)/sample.report.json --plot $(OUT)/sample.curve.png $(RELIGHT_FLAGS)

sample:
	$(CARGO) run --release -p q3gltf-samples --bin make-sample -- samples/sample

data:
	@bash $(FETCH) --oacmp >/dev/null

# Every map of the game data, one target each so that `make -j` runs them in parallel.
maps: build
	@dir="$${GAME_DIR:-$$(bash $(FETCH))}"; \
	$(MAKE) --no-print-directory GAME_DIR="$$dir" $$($(BIN) maps --game-dir "$$dir" | sed 's|.*|$(OUT)/maps/&.glb|')

$(OUT)/maps/%.glb:
	@mkdir -p $(OUT)/maps
	@$(BIN) convert $* --game-dir "$(GAME_DIR)" -q -o $@ > $(OUT)/maps/$*.log 2>&1 || { cat $(OUT)/maps/$*.log; exit 1; }
	@echo "converted $*"

$(VENV)/.stamp: tests/python/requirements.txt
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q -r tests/python/requirements.txt
	@touch $@

tests/node/node_modules/.stamp: tests/node/package.json tests/node/package-lock.json
	cd tests/node && npm ci --silent --no-audit --no-fund
	@touch $@

# Blender as a Python module (about 1 GB installed): its own venv, so .venv stays small.
$(BLENDER_VENV)/.stamp: tests/blender/requirements.txt
	$(PYTHON) -m venv $(BLENDER_VENV)
	$(BLENDER_VENV)/bin/pip install -q -r tests/blender/requirements.txt
	@touch $@

python-deps: $(VENV)/.stamp
blender-deps: $(BLENDER_VENV)/.stamp
node-deps: tests/node/node_modules/.stamp

test: test-rust test-python test-blender

test-rust: build data
	$(CARGO) test --release --workspace

test-python: build data python-deps node-deps
	Q3GLTF_BIN=$(BIN) $(VENV)/bin/python -m pytest tests/python -q -p no:cacheprovider

test-blender: build data blender-deps node-deps
	Q3GLTF_BIN=$(BIN) $(BLENDER_VENV)/bin/python -m pytest tests/blender -q -p no:cacheprovider

render: build data python-deps blender-deps
	BIN=$(BIN) OUT=$(OUT) VENV=$(VENV) BLENDER_VENV=$(BLENDER_VENV) RELIGHT_FLAGS="$(RELIGHT_FLAGS)" bash tools/game/render_views.sh

bench: build data python-deps
	$(CARGO) bench --bench convert
	@rm -rf $(OUT)/maps
	@start=$$(date +%s.%N); $(MAKE) --no-print-directory -j2 maps > /dev/null; end=$$(date +%s.%N); \
	n=$$(ls $(OUT)/maps/*.glb | wc -l); \
	line="make -j2 maps: $$n maps in $$(awk "BEGIN{printf \"%.1f\", $$end - $$start}") s (2 jobs, includes start-up of each process)"; \
	echo "$$line"; echo "$$line" >> $(OUT)/bench/convert.md
	bash benches/relight.sh $(BIN) "$${GAME_DIR:-$$(bash $(FETCH))}"
	bash benches/bake.sh $(BIN)
	$(VENV)/bin/python benches/scaling.py --bin $(BIN) --scene $(OUT)/bench/relight/oa_dm1.glb --out $(OUT)/bench
	$(VENV)/bin/python benches/thesis.py --bin $(BIN) --game-dir "$${GAME_DIR:-$$(bash $(FETCH))}" --game-dir "$$(bash $(FETCH) --oacmp)" --out $(OUT)/bench $(THESIS_BENCH_FLAGS)

# The scaling and thesis benchmarks' quick forms (the bundled sample, under a minute; CI
# runs them): out/bench/quick/{scaling,thesis}.{md,csv,svg}.
bench-quick: build python-deps
	@mkdir -p $(OUT)/bench/quick
	$(BIN) convert $(SAMPLE_BSP) -q -o $(OUT)/bench/quick/sample.glb
	$(VENV)/bin/python benches/scaling.py --quick --bin $(BIN) --scene $(OUT)/bench/quick/sample.glb --out $(OUT)/bench/quick
	$(VENV)/bin/python benches/thesis.py --quick --bin $(BIN) --out $(OUT)/bench/quick

# Fuzzing (cargo-fuzz, libFuzzer): every parser for FUZZ_SECONDS each.
fuzz: build data
	FUZZ_SECONDS=$(FUZZ_SECONDS) bash fuzz/run.sh

clean:
	rm -rf $(OUT)
	$(CARGO) clean
