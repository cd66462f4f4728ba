"""CLAMGen: closed-loop arm motion generation for a UR5 via multi-view vision-based RL."""

import os

# Headless rendering by default; a user's own MUJOCO_GL (e.g. "osmesa", "glfw") wins.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"


def _register() -> None:
    # Importing the envs package registers the Gymnasium ids.
    import clamgen.envs  # noqa: F401


_register()
