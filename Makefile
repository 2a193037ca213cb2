# Two commands do all the set-up from a fresh clone: `make demo` and `make test`.
# Both create .venv when it is missing and install the project into it: `make demo` only what
# the demo needs (pymavlink, numpy, matplotlib, numba), `make test` also the [test] extra (pytest,
# MAVProxy, RotorPy, Dask and pyarrow for offboard sweep: a few hundred MB). Each install leaves a stamp, so it runs once, and again
# only when pyproject.toml changes; demo then test, or test then demo, both work.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test
RUN    ?= runs/demo-$(shell date +%Y%m%d-%H%M%S)
TEST_WORKERS ?= 3
PIP    := $(PY) -m pip install --disable-pip-version-check --progress-bar off
# The installer: uv, a pip-compatible installer from PyPI put into the venv first, fetches and
# installs in parallel (the project and the test tools from a fresh clone in 26 s, where pip took
# 77 s of make test's 10 minutes); pip itself where uv cannot be installed or fails (pip reads this
# machine's pip.conf: its extra index and find-links, which uv does not). Byte-compiled at install,
# as pip does: where PYTHONDONTWRITEBYTECODE is set nothing else would, and every process the tests
# start would compile its imports again (make test took 2 minutes longer).
UV     := $(VENV)/bin/uv
INSTALL = if test -x $(UV) && $(UV) pip install --python $(PY) --compile-bytecode $(1); then :; \
          else echo "make: installing with pip"; $(PIP) $(1); fi
export MPLBACKEND := Agg

.PHONY: demo test test-fast bench parity install clean

$(STAMP): pyproject.toml
	@test -x $(PY) || { echo "make: creating the virtual environment $(VENV)"; $(PYTHON) -m venv $(VENV); }
	@echo "make: installing rosales-offboard and what it needs to fly (pymavlink, numpy, matplotlib, numba) into $(VENV)"
	@$(PIP) --quiet uv || echo "make: uv could not be installed; pip installs instead (slower)"
	$(call INSTALL,-e .)
	@touch $(STAMP)

$(TEST_STAMP): $(STAMP)
	@echo "make: installing the test tools (pytest; MAVProxy, a real ground station; RotorPy, the SE(3) reference; Dask and pyarrow, for offboard sweep) into $(VENV)"
	$(call INSTALL,-e '.[test]')
	@touch $(TEST_STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(PY) -m offboard.demo --run-dir $(RUN)

# three workers, a test file at a time each (its PX4 or bench fixture starts once): all the PX4 files on
# one worker (never two PX4 SITLs at once), then the files flown against a plant running free on the
# wall clock (conftest's WALL_CLOCK_MODULES: a starved plant at --speed 4 broke a flight), which takes
# nothing else and stops when they are done, and which the other two yield the cores to (tests/conftest.py); the PX4 flights wait on the wall clock
# (160-180 s of CPU in their 360 s, their PX4 SITLs and plants included), so they run beside two
# workers for the rest of the suite, not in the place of one (pytest 557 -> 455 s from cold). In the order tests/conftest.py gives them (the PX4 files and the long ones first):
# xdist >= 3.8 reorders them unless told not to. Three workers all taking any file filled the idle
# time but not the wall time (464 and 554 s against 509 and 524 s with two): the lockstep flights'
# busy-polling and the compiles shared the cores three ways to the end.
# The project byte-compiled first: each of the hundreds of processes the tests start imports it
# (0.60 -> 0.37 s a start), and where PYTHONDONTWRITEBYTECODE is set (this machine, CI) Python would
# compile it again every time. numba's kernels: the plant's compiled first (7 s from cold), so that
# every plant the tests start flies them from the first test on (a plant never compiles at start: it
# flies the interpreted physics instead); the many-vehicle ones (a minute of one core from cold) in
# the background at the lowest priority, on the cores the first tests leave idle while they wait on
# wall-clock flights, and stopped with the tests (the tests that use them come later, or compile
# what is not cached yet themselves)
test: $(TEST_STAMP)
	@$(PY) -m compileall -q offboard sitl_plant bench tests/helpers
	@$(PY) -m sitl_plant.px4_kernel
	@nice -n 19 $(PY) -m sitl_plant.dynamics.batch >/dev/null & warm=$$!; trap 'kill $$warm 2>/dev/null' EXIT INT TERM; \
	echo "$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder"; \
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

# the inner loop of development: the pure tests, no processes, no slow ones (under a minute)
test-fast: $(TEST_STAMP)
	$(PY) -m pytest -q -n 2 tests/unit -m "not slow and not e2e"

# the [bench] extra, then numba's cache warmed (a plant never compiles at start-up; no figure includes
# a compilation), then the run
bench: $(STAMP)
	@echo "make: installing the benchmark tools (numba, RotorPy, py-spy, Dask, pyarrow) into $(VENV)"
	$(call INSTALL,--quiet -e '.[bench]')
	$(PY) -m sitl_plant.px4_kernel
	$(PY) -m sitl_plant.dynamics.batch
	$(PY) bench/run.py --output bench/RESULTS.md

# docs/parity/measured.md, issue 13's table "PX4 v1.16 and sitl-plant" generated from what the tests
# measure: the px4 parity tests with their findings recorded (PARITY_FINDINGS, tests/conftest.py),
# then the page rendered from them (bench/parity.py), even when a test failed (its rows say so; make
# still fails). Needs a PX4 SITL ($$PX4_SITL, or ../shared/px4-sitl as the tests find it); a few
# minutes, one PX4 at a time (tests/conftest.py puts the PX4 files on one xdist worker: two PX4 SITLs
# at once made their timings flaky). Not part of make test or make demo.
PARITY_RUN     ?= runs/parity-findings
PARITY_WORKERS ?= 1
PARITY_TESTS   := $(sort $(wildcard tests/e2e/test_px4_parity_*.py))

parity: $(TEST_STAMP)
	@$(PY) -c 'import sys; from bench.px4sitl import SKIP_REASON, px4_launcher; sys.exit(None if px4_launcher() else "make parity: " + SKIP_REASON)'
	rm -rf $(PARITY_RUN)
	PARITY_FINDINGS=$(abspath $(PARITY_RUN)) $(PY) -m pytest -q -n $(PARITY_WORKERS) --dist loadfile -p no:cacheprovider $(PARITY_TESTS); \
	status=$$?; $(PY) -m bench.parity $(PARITY_RUN) --output docs/parity/measured.md && exit $$status

clean:
	rm -rf $(VENV) runs .pytest_cache *.egg-info
