# The set-up contract: `make demo` and `make test` work on a fresh machine with Python 3.11.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip -q --disable-pip-version-check

.PHONY: demo test lint docs bench install clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip
	# CPU torch first, so stable-baselines3 does not pull a multi-GB CUDA build (the package itself does not pin it).
	$(PIP) install torch==2.13.0
	$(PIP) install -e ".[all,test,bench,docs]"
	touch $@

install: $(VENV)/.installed

demo: $(VENV)/.installed
	MUJOCO_GL=disable $(VENV)/bin/smo-gym compare

# -n auto: one pytest worker per core (pytest-xdist); the workers share numba's on-disk cache. loadfile keeps a
# file's tests on one worker: they share compiled kernels, and some read what earlier ones recorded (sweep totals)
test: $(VENV)/.installed lint
	MUJOCO_GL=disable $(PY) -m pytest -q -m "not slow" -n auto --dist loadfile

# ruff (pinned in the test extra, so that a new release cannot reformat the tree under CI)
lint: $(VENV)/.installed
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# The documentation site (MkDocs Material + mkdocstrings), strict: any warning fails; offline, into site/.
docs: $(VENV)/.installed
	MUJOCO_GL=disable NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir site

bench: $(VENV)/.installed
	MUJOCO_GL=disable $(PY) scripts/bench_observers.py

clean:
	rm -rf $(VENV) build site *.egg-info
