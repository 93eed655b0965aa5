# bodystudio: two commands for a fresh machine.
#   make demo   set up, run the main job on the built-in synthetic studio, write a report
#   make test   set up, run the test suite
#   make lock   refresh constraints.txt (the exact versions setup installs) from the current .venv
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
# Debian packages the wheels need at run time (open3d: libusb; VTK/Open3D rendering: GL, EGL, X render;
# chromium: headless check that HTML reports load and draw).
APT_PACKAGES := libusb-1.0-0 libgomp1 libgl1 libegl1 libxrender1 chromium
DEMO_OUT ?= demo-out
PYTEST_ARGS ?=
# `make test` runs the test files as TEST_JOBS pytest processes side by side (scripts/test_shards.py; the CI
# machine has two cores); TEST_JOBS=1 runs one plain pytest. Every run prints its 25 slowest steps.
TEST_JOBS ?= 2
PYTEST := $(PY) scripts/test_shards.py --jobs $(TEST_JOBS) -- -q --durations=25
# Mutation testing (make mutate; not in CI): the core modules, each mutated with only its own fast tests.
MUTATE_MODULES ?= bodystudio/reconstruct/solver.py bodystudio/reconstruct/silhouette.py \
	bodystudio/reconstruct/rapid_skin.py bodystudio/geometry/laplacian.py bodystudio/body/skinning.py \
	bodystudio/rig/weights.py bodystudio/rig/skeleton_transfer.py bodystudio/calib/calibrate.py \
	bodystudio/capture/kinect.py bodystudio/capture/silhouettes.py \
	$(wildcard bodystudio/muscle/[!_]*.py bodystudio/mirror/[!_]*.py bodystudio/garment/[!_]*.py)
MUTATE_TIMEOUT ?= 900
MUTATE_JOBS ?= 2

.PHONY: setup demo test test-fast bench lint lock clean mutate

setup: $(VENV)/.installed
	@$(VENV)/bin/bodystudio body assets --quiet

# Installs are reproducible: every package comes at the exact version in constraints.txt (the versions the
# suite was last run with); pyproject.toml keeps the looser ranges for library users. `make lock` refreshes it.
$(VENV)/.installed: pyproject.toml constraints.txt scripts/setup_system.sh
	@bash scripts/setup_system.sh $(APT_PACKAGES)
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(PY) -m pip install -q -c constraints.txt --upgrade pip
	@$(PY) -m pip install -q -c constraints.txt -e '.[dev]'
	@touch $@

demo: setup
	$(VENV)/bin/bodystudio demo --out $(DEMO_OUT)

test: setup
	$(PYTEST) $(PYTEST_ARGS)

test-fast: setup
	$(PYTEST) -m "not slow" $(PYTEST_ARGS)

bench: setup
	$(PY) -m benchmarks.run --out docs/BENCHMARKS.md

# Writes docs/MUTATION.md (score and surviving mutants per module); one module at a time, at nice 10.
mutate: setup
	$(PY) scripts/mutate.py --timeout $(MUTATE_TIMEOUT) --jobs $(MUTATE_JOBS) --modules $(MUTATE_MODULES)

lint: setup
	$(VENV)/bin/ruff check bodystudio tests benchmarks

lock: $(VENV)/.installed
	@{ echo "# Exact versions for 'make setup' (pip install -c constraints.txt). Regenerate with 'make lock'"; \
	   echo "# after upgrading the venv and running the suite; pyproject.toml keeps the supported ranges."; \
	   $(PY) -m pip freeze --all --exclude-editable --exclude bodystudio --exclude setuptools --exclude wheel \
	   | grep -v '^#'; } > constraints.txt.tmp && mv constraints.txt.tmp constraints.txt
	@echo "wrote constraints.txt ($$(grep -vc '^#' constraints.txt) packages)"

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache
