"""CLAMGen: closed-loop arm motion generation for a UR5 via multi-view vision-based RL."""

import os

# Headless rendering by default; a user's own MUJOCO_GL (e.g. "osmesa", "glfw") wins.
os.environ.setdefault("MUJOCO_GL", "egl")
# One BLAS thread per process by default; a user's own OPENBLAS_NUM_THREADS wins. With more,
# numpy's OpenBLAS hands larger matrix products (the IK solver's duplicate test, run when a
# task is sampled) to a worker thread that then spins on another core: two evaluations at once
# on a 2-core machine each took 1.7x as long, two stage-2 training runs 1.14x
# (`benchmarks/concurrent_jobs.py`). It takes effect when numpy is first imported after this,
# as on the command line; a program that imports numpy before clamgen can set it first.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"


def _register() -> None:
    # Importing the envs package registers the Gymnasium ids.
    import clamgen.envs  # noqa: F401


_register()
