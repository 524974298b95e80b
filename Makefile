# tapcell: one entry point for a fresh machine.
#   make test           venv + package + firmware host build, C unit tests, pytest
#   make demo           the main job on the virtual printer
#   make bench          benchmarks (tables with ratios)
#   make firmware-arm   Cortex-M0+ cross build with section sizes

PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
PYTEST_WORKERS ?= 2

.PHONY: all venv firmware-host firmware-check firmware-arm test demo bench clean

all: test

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install -q --upgrade pip
	$(VPY) -m pip install -q -e '.[dev]'
	touch $@

venv: $(STAMP)

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
	rm -rf $(VENV) src/*.egg-info
