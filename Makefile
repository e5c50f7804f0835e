# fracture: build, test, demo and benchmark targets.
# Everything runs inside .venv/, created on demand, so a fresh clone needs only
# Python 3.11 and pip.

PYTHON_SYS ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV       := .venv
PY         := $(VENV)/bin/python
FRACTURE   := $(VENV)/bin/fracture
STAMP      := $(VENV)/.installed
PYTEST_ARGS ?=

.SECONDEXPANSION:
.PHONY: install web test lint demo bench goldens assets asset-reports gltf-validator check clean

PACKAGE_SOURCES := $(shell find fracture_cli -name '*.py' -not -path '*/__pycache__/*' | sort)

install: $(STAMP) $(VENV)/.kernels
	@$(MAKE) --no-print-directory web || echo "note: 'fracture view' needs its web files: run 'make web' (needs npm)"

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON_SYS) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,batch]'
	@touch $(STAMP)

# The numba kernels (the simplify stage's collapses, the triangle-pair test, the distance and ray queries, the
# cut solver's partitions and max-flow), compiled once into numba's cache (~30-40 s) so that the first bake does
# not pay for it; again when their source changes.
KERNELS := fracture_cli/jit.py fracture_cli/trigeom_kernels.py fracture_cli/trigeom_grid.py fracture_cli/trigeom_topology.py \
           fracture_cli/surface_query.py fracture_cli/surface_kernels.py \
           fracture_cli/discontinuity/partition_kernels.py fracture_cli/discontinuity/maxflow_kernel.py \
           $(wildcard fracture_cli/gameready/collapse_*.py)
$(VENV)/.kernels: $(STAMP) $(KERNELS)
	$(PY) -c "from fracture_cli.gameready.collapse_kernels import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.trigeom_kernels import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.trigeom_grid import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.trigeom_topology import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.surface_query import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.discontinuity.partition_kernels import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.discontinuity.maxflow_kernel import warm_kernels; warm_kernels()"
	@touch $@

# `fracture view`'s browser files: three.js (npm, pinned by web/package-lock.json) and the
# runtime reader, copied into the package's gitignored static/vendor/; playwright-core (for
# the browser test) stays in build/web/. Nothing from npm is committed.
WEB_VENDOR  := fracture_cli/view/static/vendor
WEB_MODULES := build/web/node_modules/.package-lock.json

web: $(WEB_VENDOR)/BUILD.json

$(WEB_MODULES): web/package.json web/package-lock.json
	@command -v npm >/dev/null 2>&1 || { echo "npm not found: 'make web' needs Node.js and npm (apt-get install npm)"; exit 1; }
	@mkdir -p build/web && cp web/package.json web/package-lock.json build/web/
	npm ci --silent --no-audit --no-fund --prefix build/web

$(WEB_VENDOR)/BUILD.json: $(WEB_MODULES) web/build.mjs engines/web/fracture_runtime.js
	node web/build.mjs build/web/node_modules $(WEB_VENDOR)

GLTF_VALIDATOR := build/node/node_modules/gltf-validator/package.json

test: install gltf-validator lint
	$(PY) -m pytest -n 2 -q $(PYTEST_ARGS)

# The lint and type gate (configured in pyproject.toml), run by `make test` before the tests.
lint: install
	$(VENV)/bin/ruff check fracture_cli tests bench
	$(VENV)/bin/mypy

# The Khronos glTF validator (npm) checks every GLB the tests bake. Optional:
# without npm the tests validate the GLB structure themselves and skip this.
gltf-validator:
	@if [ -f $(GLTF_VALIDATOR) ]; then :; \
	elif command -v npm >/dev/null 2>&1; then \
	  mkdir -p build/node && npm install --silent --no-audit --no-fund --prefix build/node gltf-validator@2.0.0-dev.3.10 \
	  || echo "note: could not install gltf-validator; its test will be skipped"; \
	else echo "note: npm not found; the Khronos glTF validator test will be skipped"; fi

# Bakes one sample asset end to end into build/demo/.
demo: install
	$(FRACTURE) -v bake sample_assets/chair.glb -o build/demo --recipe wood --preview
	@echo "demo output: $(CURDIR)/build/demo/ (chair.glb, chair.fracture.json/.bin, chair.report.json, chair.preview.png)"

bench: install
	$(PY) bench/run.py --out bench/RESULTS.md

# Validate the demo output with the Khronos glTF validator.
check: demo gltf-validator
	node scripts/validate_gltf.cjs build/node/node_modules build/demo/*.glb

goldens: install
	$(PY) -m pytest -q tests/test_golden.py --update-goldens

# Bake every sample asset with the recipe its manifest names, into build/assets/.
# Real dependencies: a second run does nothing; touching a recipe rebuilds only
# the assets that use it (directly or through `extends`).
assets: $(STAMP) build/assets.mk
	@$(MAKE) --no-print-directory -f Makefile -f build/assets.mk asset-reports

asset-reports: $$(ASSET_REPORTS)

build/assets.mk: sample_assets/manifest.toml scripts/assets_mk.py $(wildcard recipes/*.toml)
	@mkdir -p build
	$(PYTHON_SYS) scripts/assets_mk.py > $@

clean:
	rm -rf build bench/out .pytest_cache .mypy_cache .ruff_cache
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
