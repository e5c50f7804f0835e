# fracture: build, test, demo and benchmark targets.
# Everything runs inside .venv/, created on demand, so a fresh clone needs only
# Python 3.11 and pip.

PYTHON_SYS ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV       := .venv
PY         := $(VENV)/bin/python
FRACTURE   := $(VENV)/bin/fracture
STAMP      := $(VENV)/.installed
LOCK       := requirements.lock
PYTEST_ARGS ?=

.SECONDEXPANSION:
.PHONY: install lock web test lint demo bench goldens assets asset-reports gltf-validator check clean docs-images \
        docs-pattern-images

PACKAGE_SOURCES := $(shell find fracture_cli -name '*.py' -not -path '*/__pycache__/*' | sort)

install: $(STAMP) $(VENV)/.kernels
	@$(MAKE) --no-print-directory web || echo "note: 'fracture view' needs its web files: run 'make web' (needs npm)"

# The venv holds exactly what requirements.lock lists (every version and its hashes, for Python 3.11 on
# Linux x86-64, with the test and batch extras): pip refuses anything else (--require-hashes, --no-deps),
# scripts/venv_lock.py sync removes what an older lock left, and the project itself goes on top, editable,
# without dependencies or build isolation (its build backend, setuptools, is in the lock).
$(STAMP): pyproject.toml $(LOCK)
	@test -x $(PY) || $(PYTHON_SYS) -m venv $(VENV)
	@$(PY) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' || \
	  { echo "$(LOCK) is for Python 3.11; $(PY) is $$($(PY) -V): rm -rf $(VENV) and set PYTHON_SYS"; exit 1; }
	$(PY) -m pip install --quiet --require-hashes --no-deps -r $(LOCK)
	$(PY) -m pip install --quiet --no-deps --no-build-isolation -e .
	$(PY) scripts/venv_lock.py sync $(LOCK)
	@touch $(STAMP)

# Refresh the lock after changing a requirement in pyproject.toml: versions already in the lock are kept
# where they still fit; `make lock LOCK_ARGS=--upgrade` takes the newest of everything, `LOCK_ARGS='-P numpy'`
# of one package. uv (pinned, in its own venv under build/) resolves against PyPI. Any version change can
# change the bytes of a bake: after a refresh re-run `make goldens` (review the diff) and `make bench`.
# pip comes in on stdin (`-`): it is no dependency, but the installer is locked too.
UV_VERSION := 0.13.9
UV         := build/uv/bin/uv
LOCK_ARGS  ?=

$(UV):
	$(PYTHON_SYS) -m venv build/uv
	build/uv/bin/python -m pip install --quiet uv==$(UV_VERSION)

lock: $(UV)
	printf 'pip\n' | $(UV) pip compile pyproject.toml - --extra test --extra batch --generate-hashes \
	  --python-version 3.11 --python-platform x86_64-manylinux_2_35 --custom-compile-command 'make lock' \
	  --quiet -o $(LOCK) $(LOCK_ARGS)

# The numba kernels (the simplify stage's collapses, the triangle-pair test, the distance and ray queries, the
# cut solver's partitions and max-flow), compiled once into numba's cache (~30-40 s) so that the first bake does
# not pay for it; again when their source changes.
KERNELS := fracture_cli/system/jit.py fracture_cli/geometry/trigeom_kernels.py fracture_cli/geometry/trigeom_grid.py fracture_cli/geometry/trigeom_topology.py \
           fracture_cli/geometry/surface_query.py fracture_cli/geometry/surface_kernels.py \
           fracture_cli/stages/modes/solver/partition_kernels.py fracture_cli/stages/modes/solver/maxflow_kernel.py \
           fracture_cli/stages/collision/kernels.py fracture_cli/geometry/hull_kernels.py fracture_cli/geometry/mass_kernels.py \
           $(wildcard fracture_cli/stages/simplify/collapse_*.py)
$(VENV)/.kernels: $(STAMP) $(KERNELS)
	$(PY) -c "from fracture_cli.stages.simplify.warm import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.geometry.trigeom_kernels import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.geometry.trigeom_grid import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.geometry.trigeom_topology import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.geometry.surface_query import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.stages.modes.solver.partition_kernels import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.stages.modes.solver.maxflow_kernel import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.stages.collision.kernels import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.geometry.hull_kernels import warm_kernels; warm_kernels()"
	$(PY) -c "from fracture_cli.geometry.mass_kernels import warm_kernels; warm_kernels()"
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

$(WEB_VENDOR)/BUILD.json: $(WEB_MODULES) web/build.mjs engines/web/fracture_runtime.js engines/web/fracture_aligned.js
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

# Bakes one sample asset end to end into build/demo/, again only when its input, its recipe (wood, which
# extends default), the package sources or the locked dependency versions changed. The bake publishes its
# files as a set (chair.glb among them), so a failed bake leaves the old, older-than-its-inputs set behind.
DEMO := build/demo/chair.glb
DEMO_INPUTS := sample_assets/chair.glb recipes/wood.toml recipes/default.toml $(PACKAGE_SOURCES) $(LOCK)

demo: install $(DEMO)
	@echo "demo output: $(CURDIR)/build/demo/ (chair.glb, chair.fracture.json/.bin, chair.report.json, chair.preview.png)"

$(DEMO): $(DEMO_INPUTS) | $(STAMP)
	$(FRACTURE) -v bake sample_assets/chair.glb -o build/demo --recipe wood --preview

# The README's two pictures, from the demo bake: its --preview image, and `fracture view` hit on the chair's
# back in headless Chromium (web/screenshot.py, as tests/test_view_e2e.py drives it; needs `make web` and
# Debian's chromium). Again only when the demo was re-baked.
docs-images: docs/preview_chair.png docs/view_chair.png

docs/preview_chair.png: $(DEMO)
	cp build/demo/chair.preview.png $@

docs/view_chair.png: $(DEMO) web/screenshot.py web/e2e.cjs | $(WEB_VENDOR)/BUILD.json
	@command -v chromium >/dev/null 2>&1 || { echo "the screenshot needs Debian's chromium (apt-get install chromium)"; exit 1; }
	$(PY) web/screenshot.py build/demo chair $@

# The README's picture of each authored pattern kind (issue 32): a bake of a sample asset with that kind, then
# `fracture preview --panels fragments` of it (the fragments on the asset, exploded, and an impact). Each kind's
# bake is the asset, the recipe and the --set values below, as the README quotes them; again only when the
# package sources, the recipes or the lock changed.
PATTERN_KINDS := voronoi clustered radial slices bricks profile
PATTERN_BAKE_voronoi   := sample_assets/pillar.glb -r stone --set pattern.kind=voronoi --set pattern.count=24
PATTERN_BAKE_clustered := sample_assets/pillar.glb -r stone --set pattern.kind=clustered --set pattern.clusters=2 \
                          --set pattern.count=8 --set pattern.spread=0.12 --set pattern.background=4
PATTERN_BAKE_radial    := sample_assets/pane.glb -r glass_pane
PATTERN_BAKE_slices    := sample_assets/pillar.glb -r stone --set pattern.kind=slices --set pattern.slice_axes=y \
                          --set pattern.slices=5
PATTERN_BAKE_bricks    := sample_assets/wall.glb -r brick_wall
PATTERN_BAKE_profile   := sample_assets/wall.glb -r stone --set pattern.kind=profile --set pattern.cuts=6 \
                          --set 'pattern.profiles=[{ points = [[0.0, 0.0], [0.3, 0.08], [0.6, -0.08], [1.0, 0.0]] }]'
PATTERN_IMAGES := $(foreach kind,$(PATTERN_KINDS),docs/pattern_$(kind).png)
PATTERN_INPUTS := $(PACKAGE_SOURCES) $(wildcard recipes/*.toml) $(wildcard sample_assets/*.glb) $(LOCK)

docs-pattern-images: $(PATTERN_IMAGES)

# The bakes' stamps stay (make would delete them as intermediates, and bake again for the next picture).
.PRECIOUS: build/patterns/%/.baked

build/patterns/%/.baked: $(PATTERN_INPUTS) | $(STAMP)
	$(FRACTURE) -q bake $(PATTERN_BAKE_$*) -o build/patterns/$*
	@touch $@

docs/pattern_%.png: build/patterns/%/.baked
	$(FRACTURE) preview build/patterns/$*/$(basename $(notdir $(firstword $(PATTERN_BAKE_$*)))).fracture.json \
	  -o $@ --size 720 280 --panels fragments

bench: install
	$(PY) bench/run.py --out bench/RESULTS.md

# Validate the demo output with the Khronos glTF validator (again only when the demo was re-baked).
check: demo gltf-validator build/demo/.validated

build/demo/.validated: $(DEMO)
	node scripts/validate_gltf.cjs build/node/node_modules $(DEMO)
	@touch $@

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
