# limbstream: the two commands of the README are `make run` and `make test`.
# Both first install the package (building the C kernels) when its sources changed.
PYTHON ?= python3
PYTEST_ARGS ?=
STAMP := build/.installed

.PHONY: install run test test-fast icount bench m4 clean

$(STAMP): pyproject.toml setup.py $(wildcard firmware_c/src/*.c firmware_c/src/*.h firmware_c/include/*.h)
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
