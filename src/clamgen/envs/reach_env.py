"""Gymnasium environments: the UR5 moves its suction-gripper tip to a (moving) target.

## Description
A UR5 arm, moved kinematically like a position-controlled industrial arm, must bring the tip
of its suction gripper within 2 cm of a red target sphere, optionally past two green obstacles
(paper: "Arm Reaching (No Obstacle)" and "Vision-Based Arm Reaching (Obstacle-Avoidance)").

## Action space
`Box(-1, 1, (6,), float32)`: joint deltas as a fraction of `MAX_JOINT_DELTA_RAD` (0.05 rad per
20 Hz step, i.e. 1 rad/s). Values outside [-1, 1] are clipped; joint limits clip the result.
The motion is checked for collision along its path (`COLLISION_CHECK_RESOLUTION_RAD`) and stops
at the last collision-free configuration; the step then reports `collision=True`.

## Observation space
A `Dict` following the goal-conditioned convention:
- `observation`: (6,) float32 joint angles, radians (modes "joints" and "both").
- `achieved_goal`: (3,) float32 tip position, world frame, metres.
- `desired_goal`: (3,) float32 target centre, world frame, metres.
- `images`: (V, 4, H, W) uint8, RGB and depth per view, when `num_views > 0` and mode is
  "images" or "both" ((2V, 4, H, W) with `zoom_views`: the V views, then their zoomed
  views). Depth is metric depth along the optical axis mapped linearly from `DEPTH_RANGE_M` =
  (0.3, 2.5) m onto 0..255 (clipped).
- `obstacles`: (N, 8) float32, `Obstacles.as_array()`, only with `include_obstacle_state`.
- `previous_action`: (6,) float32, the joint motion the previous step made, in action units
  (`info["executed_action"]`: the commanded action where nothing stopped the arm), zeros after
  a reset; only with `previous_action` (beyond the paper: a policy's memory of its last step).

## Rewards
`-0.01` per step unless the tip is within `SUCCESS_DISTANCE_M` of the target (then 0), minus
`collision_penalty` on a step that collided. The terms are in `info["reward_step"]` and
`info["reward_collision"]` and add up to the reward.

## Starting state
Target and start joints sampled by the task family (`clamgen.tasks.TASK_FAMILIES`): "reach"
and "obstacles" as `clamgen.tasks.reach` describes (with obstacles the goal is reachable by a
collision-free IK solution and the start is collision-free); "blocked" as
`clamgen.tasks.blocked` describes (as "obstacles", and the obstacle-blind path collides).

## Episode end
Terminates on success, and on a collision when `collision_ends_episode` (a training option: a
collision then ends the episode as the evaluation rule counts it, a failure); truncates after
`max_episode_steps` (100) steps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from clamgen.robot import ur5
from clamgen.sim import constants as C
from clamgen.sim.render import (
    DEPTH_NOISE_STREAM,
    MultiViewRenderer,
    add_depth_noise,
    depth_to_uint8,
)
from clamgen.sim.scene import Obstacles, Scene
from clamgen.sim.state import SimState, images_from_render, render_state
from clamgen.tasks import TASK_FAMILIES, reach

MAX_JOINT_DELTA_RAD = 0.05
CONTROL_DT_S = 0.05
SUCCESS_DISTANCE_M = 0.02
STEP_PENALTY = 0.01
MAX_EPISODE_STEPS = 100
# Sub-step size for checking a step's path: no point of the arm moves more than ~3 cm between
# checks, less than the smallest obstacle (6 cm) plus a link's diameter (8 cm).
COLLISION_CHECK_RESOLUTION_RAD = 0.01
OBS_MODES = ("joints", "images", "both")
DEFAULT_IMAGE_SIZE = 128
# Largest view side accepted: the views of one render share an offscreen buffer of
# num_views * image_size pixels across (4096 at 4 views, within every GL implementation's
# framebuffer limit), and one 1024 px RGBD view is already 4 MiB per stored observation.
MAX_IMAGE_SIZE = 1024


@dataclass(frozen=True)
class EnvState:
    """Everything needed to resume an episode exactly: the simulator plus the target's motion."""

    sim: SimState
    target_velocity_mps: np.ndarray
    num_steps: int
    task: reach.Task | None = None
    previous_action: np.ndarray | None = None


class ReachEnv(gym.Env):
    """UR5 reaching with a suction gripper; see the module docstring for the env card.

    Args:
        num_obstacles: 0 (Reach) or more (ReachObstacles and ReachBlocked use 2).
        task_family: a name in `clamgen.tasks.TASK_FAMILIES`; None: "obstacles" when
            `num_obstacles` > 0, else "reach".
        num_views: number of cameras (0 to 4) rendered into `images`.
        image_size: height = width of each view in pixels.
        target_speed: m/s (paper: 0, 0.05, 0.1, 0.2) or "variable".
        obs_mode: "joints", "images" or "both".
        collision_penalty: magnitude (>= 0) subtracted from the reward on a colliding step.
        include_obstacle_state: add the obstacles' true poses as `obstacles` (privileged).
        collision_margin_m: contacts closer than this count as collisions (conservative).
        collision_ends_episode: a collision terminates the episode (see `compute_terminated`);
            False (the paper): the arm stops before contact and the episode goes on.
        max_episode_steps: truncation horizon (None: never; `gym.make` adds a TimeLimit).
        render_mode: None or "rgb_array" (an outside view, for videos).
        fine_depth_size: > 0: also render each view's depth alone at this size into
            `fine_depth` (V, 1, S, S) uint8, a finer depth camera at the same pose for a
            safety layer (`clamgen.experiments.depth_shield`; beyond the paper); 0: none.
        zoom_views: also render, after the V views, a zoomed view from each view camera's
            position turned to the target (`constants.ZOOM_FOVY_DEG`; beyond the paper):
            `images` is then (2V, 4, H, W).
        depth_noise_m: > 0: every depth pixel (`images`' depth channel and `fine_depth`) gets
            Gaussian noise along its ray before quantisation, of standard deviation
            `depth_noise_m * z**2` at depth z (m): the axial noise of structured-light and
            stereo RGBD cameras grows with the square of the distance (about 0.0015 for a
            Kinect v1, Khoshelham & Elberink 2012; 0.01 is a RealSense D435's 2% at 2 m).
            Drawn afresh every frame from a stream of its own (seeded by `reset(seed=...)`), so
            the tasks and the target's motion are those without noise; 0: exact depth (the
            paper's setting; beyond the paper otherwise).
        previous_action: observe the previous step's executed action as `previous_action`
            (beyond the paper: lets a policy keep to the way round an obstacle it has begun).
    """

    metadata: ClassVar[dict] = {
        "render_modes": ["rgb_array"],
        "render_fps": round(1 / CONTROL_DT_S),
    }

    def __init__(
        self,
        num_obstacles: int = 0,
        num_views: int = 0,
        image_size: int = DEFAULT_IMAGE_SIZE,
        target_speed: float | str = 0.0,
        obs_mode: str = "joints",
        collision_penalty: float = 0.0,
        include_obstacle_state: bool = False,
        collision_margin_m: float = 0.0,
        collision_ends_episode: bool = False,
        max_episode_steps: int | None = MAX_EPISODE_STEPS,
        render_mode: str | None = None,
        task_family: str | None = None,
        fine_depth_size: int = 0,
        zoom_views: bool = False,
        depth_noise_m: float = 0.0,
        previous_action: bool = False,
    ) -> None:
        num_obstacles = _integer("num_obstacles", num_obstacles, 0, C.MAX_OBSTACLES)
        task_family = task_family or ("obstacles" if num_obstacles else "reach")
        if task_family not in TASK_FAMILIES:
            raise ValueError(
                f"task_family must be one of {list(TASK_FAMILIES)}, got {task_family!r}"
            )
        if TASK_FAMILIES[task_family][1] != (num_obstacles > 0):
            raise ValueError(
                f"task_family {task_family!r} needs num_obstacles "
                f"{'>= 1' if TASK_FAMILIES[task_family][1] else '= 0'}, got {num_obstacles}"
            )
        num_views = _integer("num_views", num_views, 0, C.NUM_CAMERAS)
        if obs_mode not in OBS_MODES:
            raise ValueError(f"obs_mode must be one of {OBS_MODES}, got {obs_mode!r}")
        if obs_mode != "joints" and num_views == 0:
            raise ValueError(f"obs_mode={obs_mode!r} needs num_views >= 1")
        if obs_mode == "joints" and num_views > 0:
            # Joint observations hold no images: the views would be dropped without a word.
            raise ValueError(
                f"num_views={num_views} renders images, but obs_mode='joints' observes none: "
                "pass obs_mode='images' or 'both' to observe the views, or num_views=0"
            )
        image_size = _integer("image_size", image_size, 8, MAX_IMAGE_SIZE)
        fine_depth_size = _integer("fine_depth_size", fine_depth_size, 0, MAX_IMAGE_SIZE)
        if fine_depth_size and not num_views:
            raise ValueError("fine_depth_size renders the views' depth: it needs num_views >= 1")
        if 0 < fine_depth_size < 8:
            raise ValueError(
                f"fine_depth_size must be 0 or 8..{MAX_IMAGE_SIZE}, got {fine_depth_size}"
            )
        if not isinstance(zoom_views, bool | np.bool_):
            raise ValueError(f"zoom_views must be True or False, got {zoom_views!r}")
        if zoom_views and not num_views:
            raise ValueError("zoom_views renders a zoomed view per view: it needs num_views >= 1")
        if not (
            isinstance(depth_noise_m, int | float | np.integer | np.floating)
            and 0 <= depth_noise_m < np.inf
        ):
            raise ValueError(f"depth_noise_m must be a finite number >= 0, got {depth_noise_m!r}")
        if depth_noise_m and not num_views:
            raise ValueError("depth_noise_m perturbs the views' depth: it needs num_views >= 1")
        if not isinstance(previous_action, bool | np.bool_):
            raise ValueError(f"previous_action must be True or False, got {previous_action!r}")
        if max_episode_steps is not None:
            max_episode_steps = _integer("max_episode_steps", max_episode_steps, 1)
        if not (
            isinstance(collision_margin_m, int | float | np.integer | np.floating)
            and 0 <= collision_margin_m < np.inf
        ):
            raise ValueError(
                f"collision_margin_m must be a finite number >= 0, got {collision_margin_m!r}"
            )
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.num_obstacles = num_obstacles
        self.task_family = task_family
        self.num_views = num_views
        self.zoom_views = bool(zoom_views)
        self.image_size = image_size
        self.target_speed = reach.validate_speed(target_speed)
        self.obs_mode = obs_mode
        self.collision_penalty = collision_penalty  # validated by the setter
        self.include_obstacle_state = include_obstacle_state
        if not isinstance(collision_ends_episode, bool | np.bool_):
            raise ValueError(
                f"collision_ends_episode must be True or False, got {collision_ends_episode!r}"
            )
        self.collision_ends_episode = bool(collision_ends_episode)
        self.max_episode_steps = max_episode_steps
        self.render_mode = render_mode
        self.depth_noise_m = float(depth_noise_m)
        self._noise_rng = np.random.default_rng(DEPTH_NOISE_STREAM)

        self.scene = Scene(collision_margin_m)
        cameras = [*self.scene.camera_ids[: self.num_views]]
        if self.zoom_views:
            cameras += [*self.scene.zoom_camera_ids[: self.num_views]]
        self._renderer = (
            MultiViewRenderer(self.scene.model, cameras, image_size, image_size)
            if self.num_views
            else None
        )
        self._fine_renderer = (
            MultiViewRenderer(
                self.scene.model,
                self.scene.camera_ids[: self.num_views],
                fine_depth_size,
                fine_depth_size,
            )
            if fine_depth_size
            else None
        )
        self._overview_renderer: MultiViewRenderer | None = None
        if num_obstacles:
            self._target_box = (reach.GOAL_BOX_LOW_M, reach.GOAL_BOX_HIGH_M)
        else:
            self._target_box = (reach.REACH_BOX_LOW_M, reach.REACH_BOX_HIGH_M)

        self.action_space = gym.spaces.Box(-1.0, 1.0, (ur5.NUM_JOINTS,), np.float32)
        goal_space = gym.spaces.Box(-2.0, 2.0, (3,), np.float32)
        spaces: dict[str, gym.Space] = {}
        if obs_mode in ("joints", "both"):
            low, high = ur5.JOINT_LIMITS.T.astype(np.float32)
            spaces["observation"] = gym.spaces.Box(low, high, dtype=np.float32)
        spaces["achieved_goal"] = goal_space
        spaces["desired_goal"] = goal_space
        if self.num_views:
            shape = (len(cameras), 4, self.image_size, self.image_size)
            spaces["images"] = gym.spaces.Box(0, 255, shape, np.uint8)
        if fine_depth_size:
            shape = (self.num_views, 1, fine_depth_size, fine_depth_size)
            spaces["fine_depth"] = gym.spaces.Box(0, 255, shape, np.uint8)
        if include_obstacle_state:
            spaces["obstacles"] = gym.spaces.Box(-2.0, 2.0, (num_obstacles, 8), np.float32)
        self.previous_action = bool(previous_action)
        if self.previous_action:
            spaces["previous_action"] = self.action_space
        self.observation_space = gym.spaces.Dict(spaces)
        self._previous_action = np.zeros(ur5.NUM_JOINTS, np.float32)

        self._target_velocity = np.zeros(3)
        self._num_steps = 0
        self._task: reach.Task | None = None

    # ------------------------------------------------------------------ configuration
    @property
    def collision_penalty(self) -> float:
        """Magnitude (>= 0) subtracted on colliding steps; a curriculum may change it."""
        return self._collision_penalty

    @collision_penalty.setter
    def collision_penalty(self, value: float) -> None:
        value = float(value)
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"collision_penalty must be finite and >= 0, got {value}")
        self._collision_penalty = value

    def set_collision_penalty(self, value: float) -> None:
        """Setter usable through `VectorEnv.call` / `env.unwrapped`."""
        self.collision_penalty = value

    @property
    def task(self) -> reach.Task | None:
        """The current episode's task (None before the first reset)."""
        return self._task

    # --------------------------------------------------------------------------- API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Start an episode. `options={"task": Task}` replays a given task instead of sampling."""
        super().reset(seed=seed)
        options = options or {}
        unknown = set(options) - {"task"}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; known: ['task']")
        task = options.get("task")
        if task is None:
            sample = TASK_FAMILIES[self.task_family][0]
            task = sample(self.np_random, self.scene, self.num_obstacles, self.target_speed)
        elif not isinstance(task, reach.Task):
            raise TypeError(f"options['task'] must be a clamgen Task, got {type(task).__name__}")
        self._task = task
        if self.depth_noise_m:
            # Its own stream: with a seed, the task and the target's motion stay those without
            # noise.
            entropy = seed if seed is not None else int(self.np_random.integers(2**63))
            self._noise_rng = np.random.default_rng([entropy, DEPTH_NOISE_STREAM])
        SimState(task.start_joints, task.target_position_m, task.obstacles).apply(self.scene)
        self._target_velocity = np.array(task.target_velocity_mps, dtype=np.float64)
        self._num_steps = 0
        self._previous_action = np.zeros(ur5.NUM_JOINTS, np.float32)
        return self._observation(), self._reset_info()

    def step(self, action: np.ndarray):
        action = self._check_action(action)
        scene = self.scene
        joints = scene.data.qpos.copy()
        wanted = step_target(joints, action)
        reached, collided = scene.move_along(joints, wanted, COLLISION_CHECK_RESOLUTION_RAD)
        executed = ((reached - joints) / MAX_JOINT_DELTA_RAD).astype(np.float32)
        self._previous_action = np.clip(executed, -1.0, 1.0)
        self._move_target()
        self._num_steps += 1

        tip = scene.data.site_xpos[scene.tip_site]
        distance = float(np.linalg.norm(tip - scene.data.mocap_pos[scene.target_mocap]))
        success = distance < SUCCESS_DISTANCE_M
        reward_step = 0.0 if success else -STEP_PENALTY
        reward_collision = -self._collision_penalty if collided else 0.0
        info = {
            "is_success": success,
            "collision": collided,
            "distance_m": distance,
            "reward_step": reward_step,
            "reward_collision": reward_collision,
            "executed_action": executed,
        }
        terminated = success or (collided and self.collision_ends_episode)
        horizon = self.max_episode_steps
        truncated = horizon is not None and self._num_steps >= horizon and not terminated
        return self._observation(), reward_step + reward_collision, terminated, truncated, info

    def compute_reward(
        self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None
    ) -> np.ndarray:
        """Vectorised reward for (relabelled) goals; agrees with `step`.

        achieved_goal, desired_goal: (..., 3). info: None, a dict whose "collision" is a bool
        array of the leading shape, or a sequence of step-info dicts (as HER buffers pass).
        Returns float32 rewards of the leading shape.
        """
        reward = np.where(_reached(achieved_goal, desired_goal), 0.0, -STEP_PENALTY)
        collision = _collision_flags(info, reward.shape)
        if collision is not None:
            reward = reward - self._collision_penalty * collision
        return reward.astype(np.float32)

    def compute_terminated(
        self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None
    ) -> np.ndarray:
        """Vectorised terminal flags for (relabelled) goals; agrees with `step`: success, or a
        collision when `collision_ends_episode`. Arguments as `compute_reward`; bool array."""
        done = _reached(achieved_goal, desired_goal)
        collision = _collision_flags(info, done.shape)
        if self.collision_ends_episode and collision is not None:
            done = done | collision.astype(bool)
        return done

    def render(self) -> np.ndarray | None:
        """The outside view (480x640 RGB uint8) when render_mode == "rgb_array"."""
        if self.render_mode != "rgb_array":
            return None
        if self._overview_renderer is None:
            self._overview_renderer = MultiViewRenderer(
                self.scene.model, [self.scene.overview_camera_id], 480, 640, quality="pretty"
            )
        return self._overview_renderer.render(self.scene.data)[0][0]

    def close(self) -> None:
        for renderer in (self._renderer, self._fine_renderer, self._overview_renderer):
            if renderer is not None:
                renderer.close()

    # ------------------------------------------------- state for hindsight relabelling
    def get_state(self) -> EnvState:
        """A copy of the full state (simulator + target motion + step count)."""
        return EnvState(
            SimState.capture(self.scene),
            self._target_velocity.copy(),
            self._num_steps,
            self._task,
            self._previous_action.copy(),
        )

    def set_state(self, state: EnvState) -> None:
        """Restore a state from `get_state`; the next `step` continues from it exactly."""
        state.sim.apply(self.scene)
        self._target_velocity = np.array(state.target_velocity_mps, dtype=np.float64)
        self._num_steps = state.num_steps
        if state.task is not None:
            self._task = state.task
        if state.previous_action is not None:
            self._previous_action = np.array(state.previous_action, np.float32)

    def observe(self) -> dict[str, np.ndarray]:
        """The observation of the current state (what `reset` or `step` would return here),
        e.g. after `set_state`."""
        return self._observation()

    def render_images(
        self,
        joints: np.ndarray,
        target_position_m: np.ndarray,
        obstacles: Obstacles | None = None,
    ) -> np.ndarray:
        """Camera images (V, 4, H, W) uint8 of the arm at `joints` with the target drawn at
        `target_position_m`, without stepping and without changing the episode's state."""
        if self._renderer is None:
            raise RuntimeError("this environment renders no views (num_views=0)")
        obstacles = self.scene.obstacles if obstacles is None else obstacles
        state = SimState(np.asarray(joints, np.float64), np.asarray(target_position_m), obstacles)
        return render_state(self.scene, self._renderer, state)

    # -------------------------------------------------------------------- internals
    def _check_action(self, action: Any) -> np.ndarray:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != self.action_space.shape:
            raise ValueError(
                f"action must have shape {self.action_space.shape}, got {action.shape}"
            )
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action contains NaN or inf: {action}")
        return np.clip(action, -1.0, 1.0)

    def _move_target(self) -> None:
        if not self._target_velocity.any():
            return
        position, self._target_velocity = reach.move_target(
            self.scene.data.mocap_pos[self.scene.target_mocap],
            self._target_velocity,
            CONTROL_DT_S,
            self.target_speed if self._task is None else self._task.speed,
            self.np_random,
            *self._target_box,
        )
        self.scene.data.mocap_pos[self.scene.target_mocap] = position

    def _observation(self) -> dict[str, np.ndarray]:
        scene = self.scene
        obs: dict[str, np.ndarray] = {}
        if "observation" in self.observation_space.spaces:
            obs["observation"] = scene.data.qpos.astype(np.float32)
        obs["achieved_goal"] = scene.data.site_xpos[scene.tip_site].astype(np.float32)
        obs["desired_goal"] = scene.data.mocap_pos[scene.target_mocap].astype(np.float32)
        if self._renderer is not None:
            mujoco.mj_kinematics(scene.model, scene.data)  # mocap target moved since last update
            if self.zoom_views:
                mujoco.mj_camlight(scene.model, scene.data)  # the zoomed cameras turn to it
            rgb, depth_m = self._renderer.render(scene.data)
            obs["images"] = images_from_render(rgb, self._noisy(depth_m))
        if self._fine_renderer is not None:
            depth_m = self._noisy(self._fine_renderer.render(scene.data)[1])
            obs["fine_depth"] = depth_to_uint8(depth_m)[:, None]
        if self.include_obstacle_state:
            obs["obstacles"] = scene.obstacles.as_array()
        if self.previous_action:
            obs["previous_action"] = self._previous_action.copy()
        return obs

    def _noisy(self, depth_m: np.ndarray) -> np.ndarray:
        """`depth_m` (V, H, W) metres with the sensor noise of `depth_noise_m` (itself at 0)."""
        return add_depth_noise(depth_m, self.depth_noise_m, self._noise_rng)

    def _reset_info(self) -> dict[str, Any]:
        distance = float(np.linalg.norm(self.scene.tip_position() - self.scene.target_position))
        return {"is_success": distance < SUCCESS_DISTANCE_M, "distance_m": distance}


def step_target(joints: np.ndarray, action: np.ndarray) -> np.ndarray:
    """Where the env's joint step for `action` (in [-1, 1]; (..., 6) for several) ends:
    `MAX_JOINT_DELTA_RAD` a unit of action on each joint, joint limits applied (float64)."""
    step = np.asarray(action, np.float64) * MAX_JOINT_DELTA_RAD
    return np.clip(joints + step, *ur5.JOINT_LIMITS.T)


def _integer(name: str, value: Any, low: int, high: int | None = None) -> int:
    """`value` as an int if it is a whole number in low..high (high None: no limit), else a
    ValueError naming `name`, the value and the range."""
    allowed = f"an integer in {low}..{high}" if high is not None else f"an integer >= {low}"
    whole = isinstance(value, int | np.integer) or (
        isinstance(value, float | np.floating) and float(value).is_integer()
    )
    if isinstance(value, bool) or not whole or value < low or (high is not None and value > high):
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return int(value)


def _reached(achieved_goal: np.ndarray, desired_goal: np.ndarray) -> np.ndarray:
    """Whether each achieved goal is within `SUCCESS_DISTANCE_M` of its desired goal, (...)."""
    distance = np.linalg.norm(
        np.asarray(achieved_goal, np.float64) - np.asarray(desired_goal, np.float64), axis=-1
    )
    return distance < SUCCESS_DISTANCE_M


def _collision_flags(info: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    """Collision flags of the leading `shape` from the forms of `info` HER buffers pass."""
    if info is None:
        return None
    if isinstance(info, dict):
        if "collision" not in info:
            return None
        return np.broadcast_to(np.asarray(info["collision"], dtype=np.float64), shape)
    flags = np.array([step.get("collision", False) for step in np.ravel(info)], np.float64)
    return flags.reshape(shape)
