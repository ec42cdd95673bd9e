# limbstream: the two commands of the README are `make run` and `make test`.
PYTHON ?= python3
PYTEST_ARGS ?=

.PHONY: install run test icount bench m4 clean

install:
	$(PYTHON) -m pip install -e '.[test]'

run:
	$(PYTHON) -m limbstream.cli up

test:
	$(PYTHON) -m pytest $(PYTEST_ARGS)

icount:
	$(MAKE) -C firmware_c icount

m4:
	$(MAKE) -C firmware_c m4

bench:
	$(PYTHON) bench/kernel_speed.py

clean:
	$(MAKE) -C firmware_c clean
	rm -rf build *.egg-info limbstream/_kernels*.so
