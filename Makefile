# Two commands do everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# Two stamps: the runtime install (what `make demo` needs) and the development install (the `dev` extra:
# pytest, hypothesis, ruff, mkdocs, dask ... for `make test` and the rest). A development install includes the
# runtime one, so it refreshes both stamps; either is redone only when pyproject.toml changed since.
STAMP_RUN := $(VENV)/.installed-runtime
STAMP_DEV := $(VENV)/.installed-dev
# pip byte-compiles the ~8000 files it installs one after the other (~25 s of CPU); instead they are compiled in
# batches on every core (two fresh dev installs: 7 and 12 s shorter on two cores). As pip does, a file that does
# not compile is left alone (the interpreter reports it if it is ever imported).
COMPILE = find $(VENV)/lib -name '*.py' -print0 | \
	xargs -0 -P "$$(getconf _NPROCESSORS_ONLN 2>/dev/null || echo 2)" -n 1000 $(BIN)/python -m compileall -q >/dev/null || true

.PHONY: demo test sysdeps docs lint format bench clean

$(STAMP_RUN): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile -e .
	$(COMPILE)
	touch $(STAMP_RUN)

$(STAMP_DEV): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile -e ".[dev]"
	$(COMPILE)
	touch $(STAMP_DEV) $(STAMP_RUN)

demo: $(STAMP_RUN)
	$(BIN)/shinro-ctrl run

# Bytecode is written even where the environment sets PYTHONDONTWRITEBYTECODE: every pytest process (the xdist
# workers, the examples' pytest) otherwise re-parses and assertion-rewrites ~260 modules (this package and the
# pytest plugins: about 6 s of CPU each), and every CLI subprocess recompiles the package (__pycache__ is ignored).
test: $(STAMP_DEV) sysdeps
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest -n auto -q

# Debian packages the tests need: offscreen OpenGL for the MuJoCo video tests (MUJOCO_GL=osmesa) and headless
# Chromium for the design-report test. Installed quietly when missing (as root, or through sudo); nothing to do
# when present.
SYSDEPS := libosmesa6 chromium
sysdeps:
	@command -v dpkg >/dev/null 2>&1 || { echo "sysdeps: no dpkg here; install $(SYSDEPS) (or equivalents) yourself"; exit 0; }; \
	missing=$$(for p in $(SYSDEPS); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing system packages for the tests:" $$missing; \
		sudo=$$([ "$$(id -u)" = 0 ] || echo sudo); \
		$$sudo apt-get update -qq && $$sudo apt-get install -y -qq $$missing >/dev/null; \
	fi

# API docs site (mkdocs-material + mkdocstrings) into site/; --strict fails on any warning.
docs: $(STAMP_DEV)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

lint: $(STAMP_DEV)
	$(BIN)/ruff check shinro_ctrl tests examples benchmarks
	$(BIN)/ruff format --check shinro_ctrl tests examples benchmarks

format: $(STAMP_DEV)
	$(BIN)/ruff format shinro_ctrl tests examples benchmarks
	$(BIN)/ruff check --fix shinro_ctrl tests examples benchmarks

bench: $(STAMP_DEV)
	@for f in benchmarks/*.py; do echo "== $$f"; $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build dist *.egg-info .pytest_cache .ruff_cache
