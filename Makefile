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

test: $(STAMP)
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

bench: $(STAMP)
	$(BIN)/python bench/spline_speed.py
	$(BIN)/python bench/paper_table3.py
	$(BIN)/python bench/construction.py
	$(BIN)/python bench/torque_race.py --plot out/torque_race.png
	$(BIN)/python bench/stream_rate.py

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache
