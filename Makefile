# `make demo` and `make test` set everything up on a fresh machine (apt, venv, pip), then do their job.
# Setup is idempotent: it reruns only when pyproject.toml or constraints.txt change.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# Mesa EGL/GL for Genesis' headless cameras, libusb for open3d, chromium + its driver for the browser tests.
APT_PACKAGES := libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libgl1 libglib2.0-0 libusb-1.0-0 chromium chromium-driver

.PHONY: setup apt demo test test-slow bench lint clean

setup: $(STAMP)

apt:
	@if ! command -v dpkg >/dev/null; then echo "no dpkg: install $(APT_PACKAGES) with your package manager"; exit 0; fi; \
	missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  sudo=$$([ "$$(id -u)" = 0 ] || echo sudo); \
	  echo "apt: installing $$missing"; \
	  ( $$sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$sudo apt-get install -y -qq --no-install-recommends $$missing >/dev/null ) \
	  || echo "WARNING: could not install apt packages ($$missing); rendering robots with Genesis and the browser tests will need them"; \
	fi

$(STAMP): pyproject.toml constraints.txt
	@$(MAKE) --no-print-directory apt
	@test -x $(PY) || { echo "creating $(VENV) with $(PYTHON)"; $(PYTHON) -m venv $(VENV); }
	$(PY) -m pip install -q --upgrade pip
	@# torch first, from the local CPU wheel, so nothing later resolves to CUDA builds
	$(PY) -m pip install -q -c constraints.txt torch==2.13.0
	$(PY) -m pip install -q -c constraints.txt -e ".[dev]"
	@touch $(STAMP)

demo: setup
	$(VENV)/bin/m2m demo

test: setup
	$(VENV)/bin/pytest

test-slow: setup
	$(VENV)/bin/pytest -m slow

bench: setup
	$(VENV)/bin/m2m bench render --gaussians 100000 --size 224
	$(VENV)/bin/m2m bench render --gaussians 300000 --size 224

lint: setup
	$(VENV)/bin/ruff check src tests

clean:
	rm -rf $(VENV) workspaces .pytest_cache
