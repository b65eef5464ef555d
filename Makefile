# Two commands do all set-up: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
STUBS := .stubs
STUBS_STAMP := $(STUBS)/.installed
OUT ?= out/demo

.PHONY: setup demo test test-fast typecheck bench clean

setup: $(STAMP) $(STUBS_STAMP) sysdeps

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

# socat gives mpremote a pty "board"; installed from Debian when missing.
sysdeps:
	@command -v socat >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq socat >/dev/null; \
	  else sudo apt-get update -qq && sudo apt-get install -y -qq socat >/dev/null; fi; }

demo: setup
	$(BIN)/python tools/demo.py --out $(OUT)

# One BLAS thread per worker: pytest -n 2 on 2 cores plus BLAS threads oversubscribes the machine.
test: setup
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist loadfile
	$(MAKE) --no-print-directory typecheck

typecheck: setup
	$(BIN)/python tools/typecheck_firmware.py

bench: setup
	$(BIN)/python tools/bench.py

clean:
	rm -rf $(VENV) $(STUBS) out .pytest_cache .hypothesis
