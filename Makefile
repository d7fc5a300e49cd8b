# Two commands do all set-up: `make run` and `make test` (see README.md).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --quiet -e ".[test]"
	$(BIN)/python -m testbed.tools.warmup
	touch $(STAMP)

# The main scenario: the tripod gait down the paper's step, the EKF estimating attitude, the posture
# controller keeping the body level, recorded to MCAP and converted for the Rerun viewer.
run: $(STAMP)
	$(BIN)/testbed run --terrain step --gait tripod --estimator ekf --controller posture --duration 10 \
		--out runs/main.mcap --rerun runs/main.rrd --metrics runs/main_metrics.json --force

# The suite on TEST_WORKERS processes (pytest-xdist), a test file's tests on one of them.
TEST_WORKERS ?= 2
test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# The full benchmarks. Estimators: 5 terrains x 2 contacts x 3 IMU grades x 10 seeds x 30 s, the quad
# accelerometer array and the gyro faults (380 walks, recorded on 2 processes and cached in the user's
# cache folder; about 2 h on 2 idle cores, some 15,000 CPU s, a quarter of it the UKF's replays).
# BENCH_ARGS narrows the estimators' set with the options of `testbed bench`, e.g.
# `make bench BENCH_ARGS="--seeds 1"`. Locomotion: 183 runs on 2 processes, about 100 min, metrics cached
# in ~/.cache/hexapod-testbed/locobench; a reduced set with LOCOBENCH_SEEDS=N LOCOBENCH_LONG_DURATION=S ...
# docs/results.md is assembled from every benchmark's fragment at the end.
bench: $(STAMP)
	$(BIN)/python -m pytest -q -m bench tests/benchmarks; status=$$?; \
		$(BIN)/python -m testbed.tools.bench_report; exit $$status

clean:
	rm -rf $(VENV) runs .pytest_cache
