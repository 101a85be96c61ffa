# Quick start: `make demo` (the built-in example end to end) and `make test`.
# Both bootstrap a virtualenv in .venv with everything they need.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
export MUJOCO_GL ?= egl

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	@mkdir -p out
	$(BIN)/trajgen stream --virtual --plot out/demo.png --json out/demo.json --telemetry out/demo_telemetry.csv

# numba caches the compiled kernel keyed on fast_kernel.py alone; per_sample.py is
# what it compiles, so an edit there must make the cache stale.
trajgen/fast_kernel.py: trajgen/per_sample.py
	touch $@

test: $(STAMP) trajgen/fast_kernel.py
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

bench: $(STAMP) trajgen/fast_kernel.py
	TRAJGEN_NUMBA=1 $(BIN)/python bench/spline_speed.py --large | tee bench/results/spline_speed.md
	TRAJGEN_NUMBA=0 $(BIN)/python bench/spline_speed.py | tee bench/results/spline_speed_numpy.md
	TRAJGEN_NUMBA=0 $(BIN)/python bench/paper_table3.py | tee bench/results/paper_table3_numpy.md
	$(BIN)/python bench/paper_table3.py | tee bench/results/paper_table3.md
	$(BIN)/python bench/construction.py | tee bench/results/construction.md
	TRAJGEN_NUMBA=0 $(BIN)/python bench/stream_latency.py | tee bench/results/stream_latency_numpy.md
	TRAJGEN_NUMBA=1 $(BIN)/python bench/stream_latency.py | tee bench/results/stream_latency_numba.md
	$(BIN)/python bench/numba_load.py | tee bench/results/numba_load.md
	$(BIN)/python bench/torque_race.py --plot bench/results/torque_race.png \
		| tee bench/results/torque_race.md
	$(BIN)/python bench/stream_rate.py --seconds 3 | tee bench/results/stream_rate.md

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache
