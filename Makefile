# Two commands for a fresh machine: `make demo` (main job) and `make test` (test suite).
# Both create the virtual environment .venv on first use.
VENV ?= .venv
PY := $(VENV)/bin/python
# The CPU build of PyTorch; GPU users: `make TORCH_SPEC=torch demo` (or install their own first).
TORCH_SPEC ?= torch==2.13.0
export MUJOCO_GL ?= egl

.PHONY: install demo test lint bench clean

$(VENV)/.installed: pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet "$(TORCH_SPEC)"
	$(PY) -m pip install --quiet -e ".[dev,sweep]"
	touch $@

install: $(VENV)/.installed

# The main job on a small default: the shipped joint policy on 20 held-out tasks per target
# speed (Table 1 beside the paper), then a picture of every camera view.
demo: install
	$(VENV)/bin/clamgen eval --policy base --num-tasks 20 --out runs/demo/table1_base
	$(VENV)/bin/clamgen demo --num-episodes 3

test: install
	$(VENV)/bin/ruff check src tests benchmarks
	$(PY) -m pytest -q

bench: install
	$(PY) -m pip install --quiet -e ".[bench]"
	$(PY) benchmarks/env_steps.py
	$(PY) benchmarks/render.py
	$(PY) benchmarks/sb3_her.py

clean:
	rm -rf $(VENV) runs .pytest_cache .hypothesis
