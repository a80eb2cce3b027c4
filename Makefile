# Two entry points (see README): `make demo` runs the main job, `make test` runs every test.
# Each creates .venv and installs the project into it on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench bench-realdata clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $(STAMP)

# a mock acquisition and its identification, then an ISO 9283-style verification of that calibration on the same
# simulated robot (5 poses x 30 cycles x 3 approach directions before and after compensation: seconds in mock mode)
# (make echoes each recipe line: they stay within 80 columns, as the commands' own output does; scripts/demo_width.py)
demo: $(STAMP)
	mkdir -p sessions
	s=sessions/demo-$$(date +%Y%m%d-%H%M%S); \
	$(BIN)/acquire --robot mock:ur5e --tracker mock --session $$s.session && \
	$(BIN)/acquire verify --result $$s.result.yaml --robot mock:ur5e \
	    --tracker mock --session $$s-verify.session

# every test: on two workers (pytest-xdist; tests/conftest.py: one BLAS thread each), then the timing-sensitive
# ones (marked realtime) alone, so that no test of ours competes with them; each run lists its slowest tests, so
# that the suite's cost stays visible where it runs (CI included). The fast subset: $(BIN)/pytest -m "not slow"
test: $(STAMP)
	$(BIN)/ruff check .
	status=0; \
	$(BIN)/pytest -n 2 -m "not realtime" --durations=15 || status=1; \
	$(BIN)/pytest -m realtime --durations=5 || status=1; \
	exit $$status

lint: $(STAMP)
	$(BIN)/ruff check .

# every benchmark runs even when an earlier one misses its target; the exit status says whether any did
bench: $(STAMP)
	status=0; \
	$(BIN)/python -m bench.accuracy || status=1; \
	$(BIN)/python -m bench.full_pose || status=1; \
	$(BIN)/python -m bench.speed || status=1; \
	$(BIN)/python -m bench.trust || status=1; \
	$(BIN)/python -m bench.acquisition || status=1; \
	$(BIN)/python -m bench.trackers || status=1; \
	$(BIN)/python -m bench.ur || status=1; \
	$(BIN)/python -m bench.aruco || status=1; \
	$(BIN)/python -m bench.safety || status=1; \
	$(BIN)/python -m bench.robustness || status=1; \
	$(BIN)/python -m bench.compensation || status=1; \
	$(BIN)/python -m bench.continuous || status=1; \
	$(BIN)/python -m bench.second_session || status=1; \
	$(BIN)/python -m bench.ur_continuous || status=1; \
	$(BIN)/python -m bench.emscon_vs_ipp || status=1; \
	$(BIN)/python -m bench.camera_stream || status=1; \
	$(BIN)/python -m bench.timing_terms || status=1; \
	$(BIN)/python -m bench.region_split || status=1; \
	$(BIN)/python -m bench.flange_hold || status=1; \
	$(BIN)/python -m bench.thin_data || status=1; \
	$(BIN)/python -m bench.thin_data --noise 0.05 || status=1; \
	$(BIN)/python -m bench.thin_data --orientation 0.2 || status=1; \
	$(BIN)/python -m bench.thin_data --orientation 0.2 --noise 0.05 || status=1; \
	$(BIN)/python -m bench.startup || status=1; \
	exit $$status

# public robot-calibration data sets (never downloaded here): DATA holds one folder per set, as
# bench/realdata/README.md describes; one table per set, exit status 1 when a target is missed
bench-realdata: $(STAMP)
	@test -n "$(DATA)" || { echo "usage: make bench-realdata DATA=folder (see bench/realdata/README.md)"; exit 2; }
	$(BIN)/python -m bench.realdata "$(DATA)"

clean:
	rm -rf $(VENV) sessions
