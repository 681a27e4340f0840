# rvd-pil entry points. On a fresh Debian 12 machine each target installs what it needs.
#   make test    Debian packages + project virtualenv + build, then the whole test suite
#   make pil     the emulated PIL campaign (QEMU, Zenoh, lockstep) and its report in reports/pil
#   make bench   peer-solver and link benchmarks (prints figures; no pass/fail)
#   make asan    C++ tests under AddressSanitizer + UndefinedBehaviorSanitizer
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
JOBS ?= $(shell nproc)
NATIVE := build/native
CPP_SOURCES := $(shell find flight_sw tests/cpp -name '*.cpp' -o -name '*.hpp' -o -name 'CMakeLists.txt') CMakeLists.txt

.PHONY: test pil peers bench asan deps deps-pil venv build native clean qemu-check

deps:
	tools/install-deps test

deps-pil:
	tools/install-deps pil

# The virtualenv, with the build backend so the editable install can build without isolation.
$(VENV)/.stamp-venv: pyproject.toml | deps
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q "scikit-build-core>=0.10" "pybind11>=2.12" ninja
	$(PY) -m pip install -q -e ".[test,peers]" --no-build-isolation
	touch $@
venv: $(VENV)/.stamp-venv

# Editable install: rvd_pil's Python files stay in the tree, the module rvd_pil.flight_sw is rebuilt here.
$(VENV)/.stamp-build: $(VENV)/.stamp-venv $(CPP_SOURCES)
	$(PY) -m pip install -q -e ".[test,peers]" --no-build-isolation
	touch $@
build: $(VENV)/.stamp-build native

# Native CMake build: the flight executable and the C++ tests.
native: | deps
	cmake -S . -B $(NATIVE) -DCMAKE_BUILD_TYPE=Release -DRVD_BUILD_TESTS=ON >/dev/null
	cmake --build $(NATIVE) -j $(JOBS)

test: export OPENBLAS_NUM_THREADS = 1
test: export RVD_QEMU_FETCH = 1
test: export RVD_REQUIRE_ALL_TESTS = 1
test: build
	@# pytest runs one worker per core, each test file on one worker (module fixtures run once).
	@# The QEMU tests need the counting plugin (qemu-plugin.h from Debian's qemu source package) and
	@# the system-mode images (Debian ARM kernels, busybox): fetched once into build/, ~15 s.
	$(PY) -m rvd_pil.qemu prepare q7s rpi3
	@cd $(NATIVE) && ctest --output-on-failure -j $(JOBS); c=$$?; \
	cd $(CURDIR) && $(PY) -m pytest -q -n $(JOBS) --dist loadfile --durations=8 tests; p=$$?; \
	if [ $$c -ne 0 ] || [ $$p -ne 0 ]; then echo "make test: FAILED (ctest exit $$c, pytest exit $$p)"; exit 1; fi

asan: | deps
	cmake -S . -B build/asan -DCMAKE_BUILD_TYPE=Debug -DRVD_SANITIZE=ON -DRVD_BUILD_TESTS=ON >/dev/null
	cmake --build build/asan -j $(JOBS)
	cd build/asan && ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 ctest --output-on-failure

bench: build
	$(PY) -m pip install -q -e ".[test,peers,bench]" --no-build-isolation
	$(PY) -m rvd_pil.bench.solvers
	$(PY) -m rvd_pil.bench.target_solvers --per-cell 10
	$(PY) -m rvd_pil.bench.link_latency
	$(PY) -m rvd_pil.bench.link_auth

# The emulation platform on its own: fetches the plugin header, ARM kernels and busybox
# into build/ (python -m rvd_pil.qemu prepare), then runs every QEMU test: user mode, plugin, system mode.
qemu-check: venv | deps-pil
	$(PY) -m rvd_pil.qemu prepare
	$(PY) -m pytest -q tests/test_qemu_smoke.py tests/test_qemu_plugin.py tests/test_qemu_system.py

# The emulated PIL campaign. TARGET=q7s (or a comma-separated list) selects targets, CPU=cortex-a8
# swaps the emulated CPU model; PIL_ARGS passes more options to rvd_pil/bench/campaign.py (e.g. --full).
# GUIDANCE=PATH flies a plug-in guidance law (a folder with law.toml and its sources) instead of the
# built-in MPC, built statically for every target by the same cross toolchains (report in reports/pil-<folder>);
# a law with a [generate] step (examples/guidance/cvxpygen_*) has its C generated first, cached in build/generated.
# `make peers` runs rvd_pil/bench/peer_laws.py: our Fast MPC beside every example law (reports/peers/peers.html).
TARGET ?= q7s,rpi3
PIL_OUT ?= reports/pil$(if $(GUIDANCE),-$(notdir $(abspath $(GUIDANCE))))
pil: export OPENBLAS_NUM_THREADS = 1
pil: deps-pil build
	$(PY) -m rvd_pil.bench.campaign --targets $(TARGET) $(if $(CPU),--cpu $(CPU)) $(if $(GUIDANCE),--guidance $(GUIDANCE)) --out $(PIL_OUT) $(PIL_ARGS)

peers: export OPENBLAS_NUM_THREADS = 1
peers: deps-pil build
	$(PY) -m rvd_pil.bench.peer_laws --targets $(TARGET) $(PEERS_ARGS)

clean:
	rm -rf build
