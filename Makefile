# fracture: build, test, demo and benchmark targets.
# Everything runs inside .venv/, created on demand, so a fresh clone needs only
# Python 3.11 and pip.

PYTHON_SYS ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV       := .venv
PY         := $(VENV)/bin/python
FRACTURE   := $(VENV)/bin/fracture
STAMP      := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: install test demo bench goldens assets check clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON_SYS) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

test: install
	$(PY) -m pytest -n 2 -q $(PYTEST_ARGS)

# Bakes one sample asset end to end into build/demo/.
demo: install
	$(FRACTURE) bake sample_assets/pillar.glb -o build/demo --recipe default
	@echo "demo output: $(CURDIR)/build/demo/"

bench: install
	$(PY) bench/run.py --out bench/RESULTS.md

goldens: install
	$(PY) -m pytest -q tests/test_golden.py --update-goldens

clean:
	rm -rf build bench/out .pytest_cache
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
