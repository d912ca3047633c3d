# tissuerender — the README's two commands are `make render` and `make test`.
# Each one sets everything up on a fresh machine first: the virtual environment in .venv,
# the package with its test extra, and the Debian packages it needs (python3-venv, libosmesa6).
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.tissuerender-installed
SCENE ?= scenes/default.toml
OUT ?= out
# Two cores on the reference machine: one pytest worker each.
PYTEST_WORKERS ?= 2

.PHONY: setup render test bench clean system-deps gallery

setup: system-deps $(STAMP)

$(PY): | system-deps
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

# Debian packages the setup needs, checked before the virtual environment is made:
# python3-venv (Debian's python3 has no ensurepip without it, so `python3 -m venv` fails) and
# libosmesa6 (libOSMesa.so.8, the off-screen OpenGL of the postfx osmesa backend). As root they are
# installed with apt-get; otherwise setup stops with one message naming them.
system-deps:
	@missing=""; \
	$(PYTHON) -c 'import ensurepip, venv' 2>/dev/null || missing="$$missing python3-venv"; \
	ldconfig -p 2>/dev/null | grep -q 'libOSMesa\.so\.8' || missing="$$missing libosmesa6"; \
	if [ -z "$$missing" ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing Debian packages:$$missing"; \
	  apt-get update -q >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends $$missing >/dev/null; \
	else \
	  echo "error: missing Debian packages:$$missing; install them with: sudo apt-get install$$missing" >&2; exit 2; \
	fi

render: setup
	$(VENV)/bin/tissuerender render $(SCENE) -o $(OUT)

# One numba thread per pytest worker: two workers already fill the two cores, and oversubscribed
# parallel kernels slow down badly.
test: setup
	NUMBA_NUM_THREADS=1 $(PY) -m pytest -n $(PYTEST_WORKERS) -q tests

bench: setup
	for b in benchmarks/*.py; do echo "== $$b"; $(PY) $$b --quick || exit 1; done

# The README gallery: frame 1 of every scene in scenes/ at 320x240 into docs/gallery/NAME.png (committed); the
# scenes drawing a field colour map (the validation cases) show their last frame, where the field has grown.
GALLERY_SIZE ?= 320,240
gallery: setup
	mkdir -p docs/gallery
	for s in scenes/*.toml; do \
	  n=$$(basename $$s .toml); echo "== $$n"; \
	  $(PY) -c 'import pathlib, sys, tissuerender; from tissuerender.files import write_png; \
	    w, h = map(int, sys.argv[3].split(",")); sc = tissuerender.load_scene(sys.argv[1]); \
	    frame = sc.output.frames if any(o.field_colours for o in sc.objects) else 1; \
	    write_png(pathlib.Path(sys.argv[2]), tissuerender.render_image(sc, frame=frame, resolution=(w, h)))' \
	    $$s docs/gallery/$$n.png $(GALLERY_SIZE) || exit 1; \
	done

clean:
	rm -rf $(OUT) .pytest_cache
