# rvd-pil entry points. On a fresh Debian 12 machine each target installs what it needs.
#   make test    Debian packages + project virtualenv + build, then the whole test suite
#   make pil     (arrives with the QEMU work) the emulated PIL campaign and its report
#   make bench   peer-solver and link benchmarks (prints figures; no pass/fail)
#   make asan    C++ tests under AddressSanitizer + UndefinedBehaviorSanitizer
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
JOBS ?= $(shell nproc)
NATIVE := build/native
CPP_SOURCES := $(shell find flight_sw tests/cpp -name '*.cpp' -o -name '*.hpp' -o -name 'CMakeLists.txt') CMakeLists.txt

.PHONY: test pil bench asan deps deps-pil venv build native clean

deps:
	tools/install-deps test

deps-pil:
	tools/install-deps pil

# The virtualenv, with the build backend so the editable install can build without isolation.
$(VENV)/.stamp-venv: pyproject.toml | deps
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q "scikit-build-core>=0.10" "pybind11>=2.12" ninja
	$(PY) -m pip install -q -e ".[test]" --no-build-isolation
	touch $@
venv: $(VENV)/.stamp-venv

# Editable install: host_sim's Python files stay in the tree, the flight_sw module is rebuilt here.
$(VENV)/.stamp-build: $(VENV)/.stamp-venv $(CPP_SOURCES)
	$(PY) -m pip install -q -e ".[test]" --no-build-isolation
	touch $@
build: $(VENV)/.stamp-build native

# Native CMake build: the flight executable and the C++ tests.
native: | deps
	cmake -S . -B $(NATIVE) -DCMAKE_BUILD_TYPE=Release -DRVD_BUILD_TESTS=ON >/dev/null
	cmake --build $(NATIVE) -j $(JOBS)

test: build
	cd $(NATIVE) && ctest --output-on-failure -j $(JOBS)
	$(PY) -m pytest -q tests

asan: | deps
	cmake -S . -B build/asan -DCMAKE_BUILD_TYPE=Debug -DRVD_SANITIZE=ON -DRVD_BUILD_TESTS=ON >/dev/null
	cmake --build build/asan -j $(JOBS)
	cd build/asan && ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 ctest --output-on-failure

bench: build
	$(PY) -m pip install -q -e ".[test,bench]" --no-build-isolation
	$(PY) -m bench.solvers

pil:
	@echo "make pil arrives with the QEMU work (issue 5); nothing is emulated yet." >&2; exit 2

clean:
	rm -rf build
