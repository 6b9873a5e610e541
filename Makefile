# polcam: set-up, demo and tests on Debian bookworm.  See README.md.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.polcam-installed
DEMO_OUT ?= demo-output
PYTEST_ARGS ?=

.PHONY: all setup system demo test test-all bench clean

all: test

system:
	@bash drivers/install.sh

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev,camera,dask]'
	@touch $(STAMP)

setup: system $(STAMP)

demo: setup
	$(VENV)/bin/polcam demo --out $(DEMO_OUT)

test: setup
	$(PY) -m pytest -q -p no:cacheprovider $(PYTEST_ARGS)

test-all: setup
	$(PY) -m pytest -q -p no:cacheprovider -m '' $(PYTEST_ARGS)

clean:
	rm -rf $(VENV) $(DEMO_OUT) build *.egg-info
