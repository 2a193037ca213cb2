# Two commands do all the set-up from a fresh clone: `make demo` and `make test`.
# Both create .venv when it is missing and install the project into it.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
RUN    ?= runs/demo-$(shell date +%Y%m%d-%H%M%S)
export MPLBACKEND := Agg

.PHONY: demo test test-fast bench install clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(PY) -m offboard.demo --run-dir $(RUN)

test: $(STAMP)
	$(PY) -m pytest -q

# the inner loop of development: the pure tests, no processes, no slow ones (under a minute)
test-fast: $(STAMP)
	$(PY) -m pytest -q tests/unit -m "not slow and not e2e"

# the [bench] extra, then numba's cache warmed (a plant never compiles at start-up), then the run
bench: $(STAMP)
	$(PY) -m pip install --quiet -e '.[bench]'
	$(PY) -m sitl_plant.px4_kernel
	$(PY) bench/run.py --output bench/RESULTS.md

clean:
	rm -rf $(VENV) runs .pytest_cache *.egg-info
