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
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $@

install: $(VENV)/.installed

demo: install
	$(VENV)/bin/clamgen demo

test: install
	$(VENV)/bin/ruff check src tests benchmarks
	$(PY) -m pytest -q

bench: install
	$(PY) benchmarks/env_steps.py
	$(PY) benchmarks/render.py

clean:
	rm -rf $(VENV) runs .pytest_cache .hypothesis
