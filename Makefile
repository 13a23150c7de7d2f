# FaceCapGes — the two entry points are `make demo` and `make test`.
# Both create .venv, install the project (pinned) and what it needs from Debian/npm.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
WARM := $(VENV)/.numba-warm

.PHONY: demo test test-fast setup check clean

demo: setup $(WARM)
	$(VENV)/bin/facecapges demo --out out --force

# Both run the suite in two passes side by side (scripts/test-passes.py, docs/testing.md): the tests marked
# `serial` (they assert a rate or a wall-clock bound), collected from their files only, at the normal CPU
# policy, and beside them the rest on two pytest-xdist workers under SCHED_IDLE — it runs on the CPU time the
# serial tests leave unused, and goes back to the normal policy when they end.
# `--dist worksteal`: a worker that runs out takes half of the other's queue (tests/conftest.py puts the
# files with long tests first), so the pass does not end on one worker finishing a long test alone.
# `compileall` (0.3 s): our modules' bytecode written once, where PYTHONDONTWRITEBYTECODE would have every `live`,
# `serve` or CLI process the tests start compile them again (~0.07 s each for the 68 a live start imports).
test: setup
	bash scripts/setup-test.sh
	$(MAKE) --no-print-directory -j 2 $(WARM) check
	$(PY) -m compileall -q src
	$(PY) scripts/test-passes.py

# The inner loop (docs/testing.md): lint and every test not marked `slow` (Chromium, Blender,
# torchrun, training runs, the bench). `make test` and CI still run everything.
test-fast: setup $(WARM)
	$(VENV)/bin/ruff check src tests
	$(VENV)/bin/ruff format --check src
	$(PY) scripts/test-passes.py --fast

setup: $(STAMP)

$(STAMP): pyproject.toml package.json package-lock.json scripts/setup-capture.sh src/facecapges/capture/body_models.py scripts/setup-avatar.sh scripts/setup-runtime.sh scripts/warm-numba-caches.py
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,ray]'
	PYTHON=$(PY) bash scripts/setup-capture.sh
	PYTHON=$(PY) bash scripts/setup-avatar.sh
	bash scripts/setup-runtime.sh
	touch $(STAMP)

# Numba's on-disk caches filled in one process (ours and librosa's; see the script) before anything runs Numba
$(WARM): $(STAMP) scripts/warm-numba-caches.py
	$(PY) scripts/warm-numba-caches.py
	touch $(WARM)

# The lint and type checks: `make test` runs them beside the warm-up (its compiles take one core, mypy's workers the
# rest: a fresh clone's ~35 s warm-up and ~25 s mypy end together instead of one after the other)
check: setup
	$(VENV)/bin/ruff check src tests
	$(VENV)/bin/ruff format --check src
	$(VENV)/bin/mypy -n 2  # two worker processes: one per core (the same check; a cold cache's 37 s of CPU in half the wall)

clean:
	rm -rf $(VENV) node_modules out
