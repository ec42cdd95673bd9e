# limbstream: the two commands of the README are `make run` and `make test`.
# Both first install the package (building the C kernels) when its sources changed: `make run`
# what running needs (`pip install -e .`), `make test`, `make test-fast`, `make lint` and `make
# install` that and the test extras (`.[test]`: pytest, Chromium's driver, OpenSim, mypy, ...).
# Outside a virtual environment they make and use .venv: a stock Debian 12 / Ubuntu 24.04 python3
# refuses `pip install` into the system interpreter (PEP 668; the venv needs apt's python3-venv there).
SYSTEM_PYTHON ?= python3
ifdef VIRTUAL_ENV
PYTHON ?= python
VENV :=
else
PYTHON ?= .venv/bin/python
VENV := .venv/bin/python
endif
PYTEST_ARGS ?=
SOURCES := pyproject.toml setup.py $(wildcard firmware_c/src/*.c firmware_c/src/*.cpp firmware_c/src/*.h firmware_c/src/*.hpp firmware_c/include/*.h firmware_c/host/* firmware_c/vqf/*)
# Each stamp is newer than the sources once its install is done; the test install holds the run
# install, so it renews both stamps (make run after make test installs nothing).
STAMP := build/.installed
TEST_STAMP := build/.installed-test

.PHONY: install run test test-fast lint icount bench m4 clean

.venv/bin/python:
	$(SYSTEM_PYTHON) -m venv .venv

$(STAMP): $(SOURCES) | $(VENV)
	$(PYTHON) -m pip install -q --upgrade pip
	$(PYTHON) -m pip install -e .
	@mkdir -p build && touch $@

$(TEST_STAMP): $(SOURCES) | $(VENV)
	$(PYTHON) -m pip install -q --upgrade pip
	$(PYTHON) -m pip install -e '.[test]'
	@mkdir -p build && touch $(STAMP) $@

# everything: running, the tests and the lint
install: $(TEST_STAMP)

# make run's sensors are realistic ones: each device reads a modelled ICM-42688-P (angular rate and
# specific force, with its noise and offsets) strapped on at up to 90 deg, and fuses it on the device
# (VQF 6D, no magnetometer: its heading drifts; docs/evaluation.md, 'Raw sensors'); up calibrates
# every device from the script its stream starts with and holds the headings by the joints. The
# subjects are whole bodies (up's default layout, full: 15 devices each, chest, head, hands and feet
# too). `make run RUN_FLAGS=` runs perfect sensors, `make run RUN_FLAGS='--layout paper10'` the
# paper's 10 segments with perfect sensors; other up flags go there too.
RUN_FLAGS ?= --imu raw --imu-model icm42688p --mounting-deg 90 --heading-deg 180

run: $(STAMP)
	$(PYTHON) -m limbstream.cli up $(RUN_FLAGS)

# every test: on three workers (the end-to-end tests mostly wait on real time: the whole suite keeps
# about one core busy; a module stays on one worker), then, alone, the tests that need the cores to
# themselves: the slow end-to-end ones (a soak that counts late ticks, the clocks' timestamp errors) and the Cortex-M4 ones (up to
# ten QEMU devices at real time would starve the other workers' real-time tests of both cores)
test: $(TEST_STAMP)
	$(PYTHON) -m pytest -n 3 --dist loadfile -m "not (slow and e2e) and not qemu" $(PYTEST_ARGS)
	$(PYTHON) -m pytest -m "(slow and e2e) or qemu" $(PYTEST_ARGS)

# the edit loop: every test that needs nothing beyond Python (no processes, QEMU, browser, root),
# on 4 workers (they wait on sockets and subprocesses as much as they compute; a module stays on
# one worker, in order), property tests on their quick profile (tests/support/profiles.py).
# Bytecode is cached even where the environment says not to (PYTHONDONTWRITEBYTECODE, as in the
# Dockerfile): else every worker compiles the package and the tests and rewrites the asserts of
# pytest's plugins (hypothesis, schemathesis) again on every run, 8 of the 17 s of CPU a worker
# spends collecting.
test-fast: $(TEST_STAMP)
	PYTHONDONTWRITEBYTECODE= $(PYTHON) -m pytest -m "not (e2e or qemu or browser or root or slow)" -n 4 \
		--dist loadfile --hypothesis-profile quick $(PYTEST_ARGS)

# ruff as configured in pyproject.toml (with its complexity rule); mypy on the whole package
lint: $(TEST_STAMP)
	$(PYTHON) -m ruff check .
	$(PYTHON) -m mypy limbstream

# the firmware's build reads VQF's C++ from the vqf package installed beside limbstream
icount: $(STAMP)
	$(MAKE) -C firmware_c icount PYTHON="$$($(PYTHON) -c 'import sys; print(sys.executable)')"

m4: $(STAMP)
	$(MAKE) -C firmware_c m4 PYTHON="$$($(PYTHON) -c 'import sys; print(sys.executable)')"

bench: $(STAMP)
	$(PYTHON) bench/kernel_speed.py
	$(PYTHON) bench/pipeline.py all

clean:
	$(MAKE) -C firmware_c clean
	rm -rf build *.egg-info limbstream/_kernels*.so
