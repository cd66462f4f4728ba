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

# The main job on a small default: the shipped 2-view vision policy beside obstacle-blind IK
# interpolation on 10 held-out blocked-path tasks (both success rates printed), GIFs of the
# vision policy's first success and first failure there, then a picture of every camera view.
# Between them, the same policy acting through the depth shield and planning on the depth map
# when stuck, and that planner on the same two views with no policy (beyond the paper).
demo: install
	$(VENV)/bin/clamgen eval --table 2 --families blocked --num-tasks 10 --policy residual-2views --out runs/demo/blocked_clamgen --overwrite
	$(VENV)/bin/clamgen eval --table 2 --families blocked --num-tasks 10 --policy ik --out runs/demo/blocked_ik --overwrite
	$(VENV)/bin/clamgen eval --table 2 --families blocked --num-tasks 10 --policy residual-2views --depth-hybrid --name "residual-2views + depth shield + planner when stuck" --out runs/demo/blocked_planned --overwrite
	$(VENV)/bin/clamgen eval --table 2 --families blocked --num-tasks 10 --policy depth-rrt-2views --out runs/demo/blocked_depth_rrt --overwrite
	$(VENV)/bin/clamgen render --policy residual-2views --env-id CLAMGen/ReachBlocked-v0 --num-episodes 1 --outcome success --out runs/demo/blocked_success --overwrite
	$(VENV)/bin/clamgen render --policy residual-2views --env-id CLAMGen/ReachBlocked-v0 --num-episodes 1 --outcome failure --out runs/demo/blocked_failure --overwrite
	$(VENV)/bin/clamgen demo --num-episodes 3

test: install
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q

bench: install
	$(PY) -m pip install --quiet -e ".[bench]"
	$(PY) benchmarks/env_steps.py
	$(PY) benchmarks/render.py
	$(PY) benchmarks/render.py --quality pretty
	$(PY) benchmarks/reset_cost.py
	$(PY) benchmarks/act_latency.py
	$(PY) benchmarks/act_paths.py
	$(PY) benchmarks/first_act.py
	$(PY) benchmarks/encoder_cost.py --sizes 84 64 56 --batches 128 64 --shared yes --threads 1
	$(PY) benchmarks/update_cost.py --baseline-rev e63de27
	$(PY) benchmarks/checkpoint_stall.py
	$(PY) benchmarks/pool_gather.py
	$(PY) benchmarks/concurrent_jobs.py --training
	$(PY) benchmarks/sb3_her.py

clean:
	rm -rf $(VENV) runs .pytest_cache .hypothesis
