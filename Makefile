# depthguard: everything from a fresh clone. `make demo`, `make test`, `make bench`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
## The RealSense SDK's last version that writes ROS 1 .bag recordings, installed beside the venv
## (not into it) for the tests that play .bag recordings written by the SDK's own recorder
## (tests/realsense_recordings.py, in a subprocess); depthguard never imports it. A failed
## install is said and the tests skip, saying why (in CI, .ci/run makes that skip a failure).
BAG_SDK_VERSION := 2.57.7.10387
BAG_SDK := $(VENV)/realsense-2.57
OUT    ?= out

.PHONY: venv demo warm-up test test-fast soak bench clean

venv: $(STAMP) $(BAG_SDK)/.installed

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,bench,realsense,ur,franka]'
	touch $(STAMP)

## The main job on the built-in simulated cell.
demo: $(STAMP)
	$(VENV)/bin/depthguard demo --out $(OUT)/demo

## numba's disk cache filled before the tests, in WARM_JOBS processes side by side (a fresh clone
## compiles ~300 CPU-s of kernels; with a warm cache this only loads them, seconds).
## A failed job is named and the tests run all the same (they then compile what it would have).
WARM_JOBS ?= 2
warm-up: $(STAMP)
	-$(VENV)/bin/depthguard warm-up --jobs $(WARM_JOBS)

$(BAG_SDK)/.installed: $(STAMP)
	-$(PY) -m pip install --quiet --no-deps --target $(BAG_SDK) pyrealsense2==$(BAG_SDK_VERSION) && touch $@

## Every test (slow and multi-process ones included); the 40 slowest are listed at the end (the suite must stay well under 15 min).
## TEST_JOBS pytest-xdist processes (--dist loadfile: a module's fixtures are made once; a test
## marked realtime or multiprocess runs alone, tests/conftest.py); 0: one process. With 2 on the
## 2-core machine a fresh clone's tests took 12.7 min (1144 passed) against 16.5-18 in one process.
## --no-loadscope-reorder: the files in the collection's order, the longest first (tests/conftest.py,
## FILE_SECONDS), not xdist's by number of tests, which left the long one-test files to the end.
TEST_JOBS ?= 2
## PYTHONDONTWRITEBYTECODE (set in some environments) made pytest rewrite every test module's
## assertions in each worker on every run: collection 15-16 CPU-s a worker instead of 6 once the
## rewritten modules are cached (measured: pytest --collect-only, 1160 tests). Empty = unset.
test test-fast: export PYTHONDONTWRITEBYTECODE =
test: warm-up $(BAG_SDK)/.installed
	$(PY) -m pytest -q -p no:cacheprovider --durations=40 -n $(TEST_JOBS) --dist loadfile --no-loadscope-reorder

## Everything but the tests marked slow.
test-fast: warm-up $(BAG_SDK)/.installed
	$(PY) -m pytest -q -m "not slow" -p no:cacheprovider

## The long runs kept out of `make test` (its tests keep a short slice of each property).
soak: $(STAMP)
	$(PY) -m pytest -q -p no:cacheprovider --soak -m soak --durations=0

## Benchmarks: a table beside the papers' numbers and a peer measured in the same run.
bench: $(STAMP)
	$(VENV)/bin/depthguard bench --json $(OUT)/bench.json

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info src/*.egg-info
