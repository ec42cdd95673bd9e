# limbstream: the two commands of the README are `make run` and `make test`.
# Both first install the package (building the C kernels) when its sources changed. Outside a
# virtual environment they make and use .venv: a stock Debian 12 / Ubuntu 24.04 python3 refuses
# `pip install` into the system interpreter (PEP 668; the venv needs apt's python3-venv there).
SYSTEM_PYTHON ?= python3
ifdef VIRTUAL_ENV
PYTHON ?= python
VENV :=
else
PYTHON ?= .venv/bin/python
VENV := .venv/bin/python
endif
PYTEST_ARGS ?=
STAMP := build/.installed

.PHONY: install run test test-fast lint icount bench m4 clean

.venv/bin/python:
	$(SYSTEM_PYTHON) -m venv .venv

$(STAMP): pyproject.toml setup.py $(wildcard firmware_c/src/*.c firmware_c/src/*.cpp firmware_c/src/*.h firmware_c/include/*.h) | $(VENV)
	$(PYTHON) -m pip install -q --upgrade pip
	$(PYTHON) -m pip install -e '.[test]'
	@mkdir -p build && touch $@

install: $(STAMP)

run: $(STAMP)
	$(PYTHON) -m limbstream.cli up

test: $(STAMP)
	$(PYTHON) -m pytest $(PYTEST_ARGS)

# the edit loop: every test that needs nothing beyond Python (no processes, QEMU, browser, root)
test-fast: $(STAMP)
	$(PYTHON) -m pytest -m "not (e2e or qemu or browser or root or slow)" $(PYTEST_ARGS)

# ruff as configured in pyproject.toml; mypy on the wire contract
lint: $(STAMP)
	$(PYTHON) -m ruff check .
	$(PYTHON) -m mypy limbstream/wire

icount:
	$(MAKE) -C firmware_c icount

m4:
	$(MAKE) -C firmware_c m4

bench: $(STAMP)
	$(PYTHON) bench/kernel_speed.py
	$(PYTHON) bench/pipeline.py all

clean:
	$(MAKE) -C firmware_c clean
	rm -rf build *.egg-info limbstream/_kernels*.so
