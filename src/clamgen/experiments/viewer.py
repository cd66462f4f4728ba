"""`clamgen view`: MuJoCo's interactive viewer on seeded tasks, with a policy acting live.

The viewer is MuJoCo's passive viewer on the env's own model and data
(`env.unwrapped.scene.model` / `.data`), so it draws exactly what the env steps: the arm, the
red target sphere and the green obstacles. On top of them it draws each camera's frustum (the
policy's cameras bright, the others dim), the tip's path so far, and a status panel. The
policy acts through the shared rollout loop (`evaluate.run_episode`); the viewer watches each
step through its step hook, which also holds the loop while paused.

Keys: Space pauses and resumes; Right arrow takes one step (and pauses); Backspace restarts
the episode. The mouse moves the camera as in MuJoCo's `simulate`; Tab shows its menus. The
run is bounded by `--max-steps` and `--seconds` so that scripts and tests end; without them it
runs until the window is closed.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import mujoco
import numpy as np

from clamgen.envs import CONTROL_DT_S, ENV_IDS, ENV_TASKS, ReachEnv
from clamgen.experiments.config import check_task_seed
from clamgen.experiments.evaluate import run_episode
from clamgen.experiments.policies import PolicyName

# GLFW key codes, as MuJoCo's passive viewer passes them to its key callback.
KEY_SPACE, KEY_RIGHT, KEY_BACKSPACE = 32, 262, 259
KEYS_HELP = "Space: pause/resume   Right: one step   Backspace: restart episode"
# Frustum colours: nothing else in the scene is cyan or violet.
POLICY_CAMERA_RGBA = (0.0, 0.9, 1.0, 1.0)
OTHER_CAMERA_RGBA = (0.7, 0.4, 1.0, 1.0)
TIP_PATH_RGBA = (1.0, 0.85, 0.0, 1.0)
MAX_PATH_POINTS = 300
VIEWER_EXIT_TIMEOUT_S = 30.0
# The free camera's start: the outside view's direction, far enough back to show the cameras.
VIEW_LOOKAT_M = (0.45, 0.0, 0.25)
VIEW_DISTANCE_M, VIEW_AZIMUTH_DEG, VIEW_ELEVATION_DEG = 2.7, 140.0, -25.0


@dataclass(frozen=True)
class ViewConfig:
    """Watch a policy act on seeded tasks in MuJoCo's interactive viewer."""

    policy: PolicyName | Path = "ik"
    """A shipped policy, a baseline (`ik`: IK interpolation, `rrt`: RRT-Connect with the full
    scene model) or a policy file trained on a CLAMGen env."""
    env_id: Literal[ENV_IDS] = ENV_IDS[1]
    """CLAMGen env whose task family samples the tasks."""
    seed: int = 1_000_000_000
    """Reset seed of the first task (task i: seed + i; default: the first test task)."""
    num_episodes: int = 1
    """Tasks to show, one after the other; the last stays on screen until the window closes."""
    target_speed: str = "0"
    """Target speed in m/s, or `variable`."""
    steps_per_second: float = 1 / CONTROL_DT_S
    """Policy steps per second of wall time (default: the control rate, i.e. real time)."""
    paused: bool = False
    """Start paused (Space resumes, Right arrow steps once)."""
    max_steps: int | None = None
    """Close the viewer after this many policy steps in all (None: no limit). Episodes that
    end sooner leave the last one on screen until the window closes or `--seconds` is up."""
    seconds: float | None = None
    """Close the viewer after this many seconds from when it opened (None: no limit)."""
    frustum_depth_m: float = 0.4
    """How far from each camera its drawn frustum reaches, metres."""


class _Stop(Exception):
    """Ends the session: window closed, step budget spent or time up (the reason)."""


class _Restart(Exception):
    """Backspace: run the current task again from its start."""


class _Keys:
    """Key presses from the viewer's thread, read by the rollout's step hook."""

    def __init__(self, paused: bool) -> None:
        self._lock = threading.Lock()
        self.paused = paused
        self._steps_requested = 0
        self._restart = False

    def __call__(self, keycode: int) -> None:
        with self._lock:
            if keycode == KEY_SPACE:
                self.paused = not self.paused
            elif keycode == KEY_RIGHT:
                self.paused = True
                self._steps_requested += 1
            elif keycode == KEY_BACKSPACE:
                self._restart = True

    def take_step(self) -> bool:
        with self._lock:
            if self._steps_requested:
                self._steps_requested -= 1
                return True
            return False

    def take_restart(self) -> bool:
        with self._lock:
            restart, self._restart = self._restart, False
            return restart


def camera_frustum_segments(
    model: mujoco.MjModel, data: mujoco.MjData, camera_id: int, depth_m: float
) -> np.ndarray:
    """The 8 edges (8, 2, 3) of a camera's viewing pyramid out to `depth_m`, world frame,
    metres: 4 from the camera to the corners of the far rectangle, and its 4 sides. Square
    images (the env's views are square); MuJoCo cameras look along their -z axis, +y up."""
    position = data.cam_xpos[camera_id]
    axes = data.cam_xmat[camera_id].reshape(3, 3)  # columns: camera x, y, z in world
    half = depth_m * np.tan(np.deg2rad(model.cam_fovy[camera_id]) / 2)
    centre = position - depth_m * axes[:, 2]
    signs = ((-1, -1), (1, -1), (1, 1), (-1, 1))
    corners = [centre + half * (sx * axes[:, 0] + sy * axes[:, 1]) for sx, sy in signs]
    rays = [(position, corner) for corner in corners]
    sides = [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    return np.array(rays + sides)


class _LiveView:
    """The rollout's step hook: draws the step in the viewer, then holds the loop until the
    next step is due (paced, paused or single-stepped)."""

    def __init__(self, handle, env: ReachEnv, keys: _Keys, config: ViewConfig, label: str):
        self.handle, self.env, self.keys, self.config, self.label = handle, env, keys, config, label
        self.num_policy_views = 0
        self.deadline = None if config.seconds is None else time.monotonic() + config.seconds
        self.total_steps = 0
        self.episode = 0
        self.tips: list[np.ndarray] = []
        self.collided = False
        self.status = "running"
        self._single_step = False
        self._next_step_at = 0.0

    def start_episode(self, episode: int) -> None:
        self.episode, self.tips, self.collided = episode, [], False

    def __call__(self, obs: dict[str, Any], info: dict[str, Any] | None, done: bool) -> None:
        self.tips.append(np.array(obs["achieved_goal"], dtype=np.float64))
        if info is not None:
            self.total_steps += 1
            self.collided |= bool(info["collision"])
            if self._single_step:
                print(
                    f"step {len(self.tips) - 1}: tip {info['distance_m']:.3f} m from the target,"
                    f" collision: {bool(info['collision'])}",
                    flush=True,
                )
        self.draw()
        if done:
            return
        if self.config.max_steps is not None and self.total_steps >= self.config.max_steps:
            raise _Stop(f"{self.total_steps} steps")
        self._wait_for_next_step()

    def hold(self) -> None:
        """After the last episode: keep the final state on screen until the window closes or
        time is up."""
        self.status = "finished"
        self.draw()
        while True:
            self._check_open()
            time.sleep(0.05)

    def _check_open(self) -> None:
        if not self.handle.is_running():
            raise _Stop("window closed")
        if self.deadline is not None and time.monotonic() >= self.deadline:
            raise _Stop(f"{self.config.seconds:g} s")

    def _wait_for_next_step(self) -> None:
        self._single_step = False
        while True:
            self._check_open()
            if self.keys.take_restart():
                raise _Restart
            if self.keys.take_step():
                self._single_step = True
                break
            now = time.monotonic()
            if not self.keys.paused and now >= self._next_step_at:
                break
            if self.status != ("paused" if self.keys.paused else "running"):
                self.draw()
            time.sleep(0.01)
        self._next_step_at = time.monotonic() + 1.0 / self.config.steps_per_second

    def draw(self) -> None:
        """Frusta, tip path and status panel into the viewer, then sync it with the data."""
        if self.status != "finished":
            self.status = "paused" if self.keys.paused else "running"
        scene = self.env.scene
        with self.handle.lock():
            user_scn = self.handle.user_scn
            user_scn.ngeom = 0
            for i, camera_id in enumerate(scene.camera_ids):
                rgba = POLICY_CAMERA_RGBA if i < self.num_policy_views else OTHER_CAMERA_RGBA
                segments = camera_frustum_segments(
                    scene.model, scene.data, camera_id, self.config.frustum_depth_m
                )
                for start, end in segments:
                    _add_line(user_scn, start, end, rgba)
            for tip in self.tips[-MAX_PATH_POINTS:]:
                _add_sphere(user_scn, tip, 0.006, TIP_PATH_RGBA)
        steps = len(self.tips) - 1
        seed = self.config.seed + self.episode
        state = "COLLISION" if self.collided else self.status
        self.handle.set_texts(
            [
                (
                    None,
                    mujoco.mjtGridPos.mjGRID_TOPLEFT,
                    "policy\nepisode\nstep\nstate",
                    f"{self.label}\n{self.episode + 1}/{self.config.num_episodes} (seed {seed})"
                    f"\n{steps}\n{state}",
                ),
                (None, mujoco.mjtGridPos.mjGRID_BOTTOMLEFT, KEYS_HELP, ""),
            ]
        )
        self.handle.sync()


def _add_line(scn: mujoco.MjvScene, start, end, rgba) -> None:
    if scn.ngeom >= scn.maxgeom:
        return
    geom = scn.geoms[scn.ngeom]
    mujoco.mjv_initGeom(
        geom, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(), rgba
    )
    mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_LINE, 2.0, start, end)
    scn.ngeom += 1


def _add_sphere(scn: mujoco.MjvScene, centre, radius_m: float, rgba) -> None:
    if scn.ngeom >= scn.maxgeom:
        return
    mujoco.mjv_initGeom(
        scn.geoms[scn.ngeom],
        mujoco.mjtGeom.mjGEOM_SPHERE,
        np.full(3, radius_m),
        np.asarray(centre, np.float64),
        np.eye(3).ravel(),
        np.asarray(rgba, np.float32),
    )
    scn.ngeom += 1


def check_display() -> None:
    """A one-line ValueError when no display is there for the viewer's window."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise ValueError(
            "clamgen view needs a display and DISPLAY is not set; on a headless machine run "
            "it under a virtual one: xvfb-run -a -s '-screen 0 1280x960x24' clamgen view ..."
        )


def view(config: ViewConfig, policy, label: str, env_kwargs: dict | None = None) -> dict:
    """Open the viewer on `config.num_episodes` seeded tasks with `policy` acting; returns what
    happened (episodes, steps, why it stopped). One-line ValueErrors for bad options."""
    import mujoco.viewer

    from clamgen.tasks.reach import validate_speed

    if config.env_id not in ENV_IDS:
        raise ValueError(f"--env-id must be one of {ENV_IDS}, got {config.env_id!r}")
    if config.num_episodes < 1:
        raise ValueError(f"--num-episodes must be >= 1, got {config.num_episodes}")
    check_task_seed(config.seed)
    if config.steps_per_second <= 0:
        raise ValueError(f"--steps-per-second must be > 0, got {config.steps_per_second}")
    if config.max_steps is not None and config.max_steps < 1:
        raise ValueError(f"--max-steps must be >= 1, got {config.max_steps}")
    if config.seconds is not None and config.seconds <= 0:
        raise ValueError(f"--seconds must be > 0, got {config.seconds}")
    env_kwargs = dict(env_kwargs or {})
    if env_kwargs.get("num_views") and os.environ.get("MUJOCO_GL") not in ("egl", "osmesa"):
        # The viewer's window owns GLFW in its own thread; the policy's views need another,
        # offscreen GL.
        raise ValueError(
            "this policy observes camera views, rendered offscreen beside the viewer's window: "
            "set MUJOCO_GL=egl (or osmesa)"
        )
    check_display()
    speed = validate_speed(
        config.target_speed if config.target_speed == "variable" else float(config.target_speed)
    )
    num_obstacles, family = ENV_TASKS[config.env_id]
    env = ReachEnv(
        num_obstacles=num_obstacles, task_family=family, target_speed=speed, **env_kwargs
    )
    env.reset(seed=config.seed)  # the first task is on screen as the window opens
    keys = _Keys(config.paused)
    print("opening MuJoCo's viewer ...", flush=True)
    threads_before = set(threading.enumerate())
    handle = mujoco.viewer.launch_passive(
        env.scene.model,
        env.scene.data,
        key_callback=keys,
        show_left_ui=False,
        show_right_ui=False,
    )
    with handle.lock():
        handle.cam.lookat[:] = VIEW_LOOKAT_M
        handle.cam.distance = VIEW_DISTANCE_M
        handle.cam.azimuth = VIEW_AZIMUTH_DEG
        handle.cam.elevation = VIEW_ELEVATION_DEG
    live = _LiveView(handle, env, keys, config, label)
    live.num_policy_views = env.num_views or int(env_kwargs.get("num_views", 0))
    print(f"viewer open: {KEYS_HELP}; close the window to stop", flush=True)
    episodes: list[dict[str, Any]] = []
    reason = "window closed"
    try:
        episode = 0
        while episode < config.num_episodes:
            live.start_episode(episode)
            seed = config.seed + episode
            try:
                record = run_episode(env, policy, seed, on_step=live)
            except _Restart:
                print(f"episode {episode} (seed {seed}): restarted", flush=True)
                continue
            episodes.append(record.outcome())
            print(
                f"episode {episode} (seed {seed}): {'success' if record.success else 'failure'}"
                f" in {record.steps} steps, collision: {record.collided}",
                flush=True,
            )
            episode += 1
        live.hold()
    except _Stop as stop:
        reason = str(stop)
    finally:
        handle.close()
        # The window's thread tears down its GL context and GLFW after the close request;
        # exiting (GLFW's atexit terminate) or closing the env's EGL contexts under it crashes.
        for thread in set(threading.enumerate()) - threads_before:
            thread.join(timeout=VIEWER_EXIT_TIMEOUT_S)
        env.close()
    print(f"viewer closed ({reason}) after {live.total_steps} steps", flush=True)
    return {
        "policy": label,
        "env_id": config.env_id,
        "episodes": episodes,
        "steps": live.total_steps,
        "stopped": reason,
    }
