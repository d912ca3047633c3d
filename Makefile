# tissuerender — the README's two commands are `make render` and `make test`.
# Each one sets everything up on a fresh machine first: the virtual environment in .venv,
# the package with its test extra, and the OSMesa system library (Debian libosmesa6).
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.tissuerender-installed
SCENE ?= scenes/default.toml
OUT ?= out
# Two cores on the reference machine: one pytest worker each.
PYTEST_WORKERS ?= 2

.PHONY: setup render test bench clean system-deps

setup: $(STAMP) system-deps

$(PY):
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

# libOSMesa.so.8 backs the off-screen OpenGL post-effects backend (postfx osmesa).
system-deps:
	@if ldconfig -p 2>/dev/null | grep -q 'libOSMesa\.so\.8'; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing Debian package libosmesa6 (off-screen OpenGL for postfx)"; \
	  apt-get update -q >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends libosmesa6 >/dev/null; \
	else \
	  echo "warning: libOSMesa.so.8 not found; install the Debian package libosmesa6 (sudo apt-get install libosmesa6)." >&2; \
	  echo "         Until then the osmesa post-effects backend is unavailable and backend = \"auto\" uses numpy." >&2; \
	fi

render: setup
	$(VENV)/bin/tissuerender render $(SCENE) -o $(OUT)

# One numba thread per pytest worker: two workers already fill the two cores, and oversubscribed
# parallel kernels slow down badly.
test: setup
	NUMBA_NUM_THREADS=1 $(PY) -m pytest -n $(PYTEST_WORKERS) -q tests

bench: setup
	for b in benchmarks/*.py; do echo "== $$b"; $(PY) $$b --quick || exit 1; done

clean:
	rm -rf $(OUT) .pytest_cache
