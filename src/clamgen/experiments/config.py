"""Training configuration: nested frozen dataclasses (env / agent / replay / loop) and presets.

Presets are TOML files in `clamgen/presets/` (or any path): tables `[env]`, `[agent]`,
`[replay]`, `[loop]` override the defaults below; the command line overrides the preset.
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
import types
import typing
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from clamgen.agents.sac import SACConfig
from clamgen.envs import ENV_IDS
from clamgen.envs.reach_env import MAX_IMAGE_SIZE, OBS_MODES
from clamgen.replay.buffer import ReplayConfig
from clamgen.schedules import Constant, LinearRamp, Schedule
from clamgen.sim.constants import NUM_CAMERAS
from clamgen.tasks.reach import validate_speed

PRESET_DIR = Path(__file__).resolve().parent.parent / "presets"


# ------------------------------------------------------------------------------- seeds
@dataclass(frozen=True)
class SeedRange:
    """Reset seeds `start <= seed < stop` set aside for one purpose."""

    name: str
    start: int
    stop: int

    def __contains__(self, seed: object) -> bool:
        return isinstance(seed, int | np.integer) and self.start <= int(seed) < self.stop

    def seeds(self, count: int, first: int | None = None) -> np.ndarray:
        """`count` consecutive seeds (int64) from `first` (default: the range's start); a
        ValueError if any falls outside the range."""
        first = self.start if first is None else int(first)
        if count < 0:
            raise ValueError(f"count must be >= 0, got {count}")
        if count and (first not in self or first + count - 1 not in self):
            raise ValueError(
                f"seeds {first}..{first + count - 1} are not all {self.name} seeds "
                f"({self.start}..{self.stop - 1}){_range_hint(first)}"
            )
        return first + np.arange(count, dtype=np.int64)

    def __str__(self) -> str:
        return f"{self.name} seeds {self.start}..{self.stop - 1}"


# Three disjoint ranges of env reset seeds (every task is a function of its seed):
# - training: the environments a policy learns in (`loop.seed * TRAINING_ENV_SEED_STRIDE + env
#   index`, after which each env continues its own random stream) and any scenes rendered for
#   pretraining;
# - validation: periodic evaluation during training and every choice among runs or settings;
# - test: the tables (`clamgen eval --table 1/2`); nothing is chosen by looking at them. The
#   test range starts where the committed tables' seeds always started, so they stay valid.
TRAINING_SEEDS = SeedRange("training", 0, 1_000_000_000)
TEST_SEEDS = SeedRange("test", 1_000_000_000, 2_000_000_000)
VALIDATION_SEEDS = SeedRange("validation", 2_000_000_000, 3_000_000_000)
SEED_RANGES = (TRAINING_SEEDS, VALIDATION_SEEDS, TEST_SEEDS)
# Training env i of a run with loop seed s is reset with seed s * stride + i.
TRAINING_ENV_SEED_STRIDE = 1000
MAX_TRAINING_LOOP_SEED = TRAINING_SEEDS.stop // TRAINING_ENV_SEED_STRIDE - 1


def _range_hint(seed: int) -> str:
    for seed_range in SEED_RANGES:
        if seed in seed_range:
            return f"; {seed} is a {seed_range.name} seed"
    return ""


def check_table_seeds(first: int, count: int) -> np.ndarray:
    """The seeds of a table's `count` tasks from `first`: test seeds only (a ValueError names
    the range a refused seed belongs to, e.g. validation)."""
    return TEST_SEEDS.seeds(count, first)


def check_task_seed(seed: int) -> int:
    """A task seed for the commands that show tasks (`demo`, `export-scene`, `render`, `view`):
    any seed >= 0 (showing a training or validation task tunes nothing); a ValueError else."""
    if seed < 0:
        raise ValueError(f"--seed must be >= 0, got {seed}")
    return seed


def check_training_seed(seed: int) -> int:
    """A training loop seed whose env seeds all lie in the training range; a ValueError else."""
    if not (isinstance(seed, int | np.integer) and 0 <= seed <= MAX_TRAINING_LOOP_SEED):
        raise ValueError(
            f"loop.seed must be in 0..{MAX_TRAINING_LOOP_SEED} so that its env seeds (seed * "
            f"{TRAINING_ENV_SEED_STRIDE} + env index) are training seeds, got {seed}"
            f"{_range_hint(seed) if seed not in TRAINING_SEEDS else ''}"
        )
    return int(seed)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


def _require_int(name: str, value: object, low: int, high: int | None = None) -> None:
    """A ValueError naming `name` unless `value` is an integer in low..high (high: no limit)."""
    is_int = isinstance(value, int | np.integer) and not isinstance(value, bool)
    if not is_int or value < low or (high is not None and value > high):
        allowed = f"an integer >= {low}" if high is None else f"an integer in {low}..{high}"
        raise ValueError(f"{name} must be {allowed}, got {value!r}")


# A training clearance beyond this (m) would reject most obstacle tasks' starts and goals.
MAX_TRAINING_COLLISION_MARGIN_M = 0.1


@dataclass(frozen=True)
class EnvConfig:
    """Which environment to train in, and how many copies step in lockstep."""

    env_id: str = ENV_IDS[0]
    """Gymnasium id (`CLAMGen/Reach-v0`, `CLAMGen/ReachObstacles-v0`, or any goal env)."""
    target_speed: float | str = 0.0
    """Training target speed in m/s, or "variable" (CLAMGen envs only)."""
    num_envs: int = 4
    """Environments stepped together; the policy acts on all of them in one batch."""
    num_views: int = 0
    """Camera views rendered into observations (0: joint observations only)."""
    image_size: int = 128
    """Side in pixels of each view."""
    obs_mode: Literal["joints", "images", "both"] = "joints"
    """"joints", "images" or "both" (CLAMGen envs)."""
    collision_penalty: Schedule = field(default_factory=Constant)
    """Collision penalty over training progress (paper: LinearRamp(0.3, 0.9, 0.0, 0.1))."""
    include_obstacle_state: bool = False
    """Add the obstacles' true poses to observations (for the privileged residual)."""
    training_collision_margin_m: float = 0.0
    """Beyond the paper: the training envs count contacts closer than this (m) as collisions, so
    the arm stops short of them and the step is penalised, and the policy learns to keep this
    clearance (an RRT teacher, `loop.teacher_fraction`, then plans with it too). Periodic
    validation and every table use true contact (0). 0: the paper."""
    zoom_views: bool = False
    """Beyond the paper: each view camera also renders a zoomed view turned to the target
    (`ReachEnv(zoom_views=True)`), so images hold 2 x num_views views (the encoder's
    `num_views` counts both). Students only: stage-2 RL's image HER does not re-render them."""
    collision_ends_episode: bool = False
    """Beyond the paper: in the training envs a collision ends the episode and its transition is
    terminal, so that the learner values a collision as the evaluation rule counts it, a
    failure, instead of stopping at the obstacle and sliding on. The collision penalty is then
    the whole cost of a collision: give it at least the value of never arriving,
    `STEP_PENALTY / (1 - agent.gamma)` (0.5 at gamma 0.98) from the start of training, or
    ending the episode by a collision pays better than trying. Periodic validation and every
    table are unchanged. False: the paper."""
    depth_noise_m: float = 0.0
    """Beyond the paper: train (and validate periodically) on noisy depth, as a real RGBD camera
    gives it: Gaussian noise along each depth ray, sd `depth_noise_m * z**2` m at depth z
    (`ReachEnv(depth_noise_m=...)`; about 0.0015 for a Kinect v1, 0.01 for a RealSense D435).
    Image HER's re-rendered episodes get the same noise. The tables pick their own
    (`clamgen eval --depth-noise-m`). 0: exact depth (the paper)."""
    previous_action: bool = False
    """Beyond the paper: observations also hold the previous step's executed action
    (`ReachEnv(previous_action=True)`), for a policy that reads it (`agent.previous_action`).
    False: the paper."""

    def __post_init__(self) -> None:
        _require_int("env.num_envs", self.num_envs, 1)
        margin = self.training_collision_margin_m
        if not (_is_number(margin) and 0 <= margin <= MAX_TRAINING_COLLISION_MARGIN_M):
            raise ValueError(
                "env.training_collision_margin_m must be a number in "
                f"[0, {MAX_TRAINING_COLLISION_MARGIN_M}] (metres), got {margin!r}"
            )
        _require_int("env.num_views", self.num_views, 0, NUM_CAMERAS)
        _require_int("env.image_size", self.image_size, 8, MAX_IMAGE_SIZE)
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"env.obs_mode must be one of {OBS_MODES}, got {self.obs_mode!r}")
        noise = self.depth_noise_m
        if not (_is_number(noise) and 0 <= noise < float("inf")):
            raise ValueError(f"env.depth_noise_m must be a finite number >= 0, got {noise!r}")
        if noise and self.num_views == 0:
            raise ValueError(
                "env.depth_noise_m perturbs the views' depth: it needs env.num_views >= 1"
            )
        if self.zoom_views and self.num_views == 0:
            raise ValueError("env.zoom_views needs env.num_views >= 1 (a zoomed view per view)")
        if (self.num_views > 0) != (self.obs_mode != "joints"):
            raise ValueError(
                f"env.num_views={self.num_views} does not fit env.obs_mode={self.obs_mode!r}: "
                "views need obs_mode 'images' or 'both', and those modes need num_views >= 1"
            )
        try:
            validate_speed(self.target_speed)
        except ValueError as error:
            raise ValueError(f"env.target_speed: {error}") from None

    def make_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for `gym.make` of a CLAMGen env."""
        return {
            "target_speed": self.target_speed,
            "num_views": self.num_views,
            "image_size": self.image_size,
            "obs_mode": self.obs_mode,
            "include_obstacle_state": self.include_obstacle_state,
            **({"zoom_views": True} if self.zoom_views else {}),
            **({"depth_noise_m": self.depth_noise_m} if self.depth_noise_m else {}),
            **({"previous_action": True} if self.previous_action else {}),
        }


@dataclass(frozen=True)
class LoopConfig:
    """The training loop: budget, update ratio, evaluation, checkpoints, logging."""

    total_env_steps: int = 60_000
    """Environment steps (summed over all envs) to train for."""
    learning_starts: int = 2_000
    """Steps of uniformly random actions before the first update."""
    updates_per_step: float = 0.5
    """Gradient updates per environment step."""
    eval_every_steps: int = 5_000
    """Evaluate the deterministic policy every this many env steps (0: never)."""
    num_eval_episodes: int = 50
    """Episodes per periodic evaluation, on fixed evaluation seeds."""
    checkpoint_every_steps: int = 5_000
    """Write a resumable checkpoint every this many env steps."""
    log_every_steps: int = 1_000
    """Write metrics (CSV, TensorBoard) every this many env steps."""
    seed: int = 0
    """Seed of the environments, the agent and the replay sampling; 0..999999, so that env i's
    reset seed, seed * 1000 + i, is a training seed (`TRAINING_SEEDS`)."""
    torch_threads: int = 1
    """Threads PyTorch may use. One by default: measured on the 2-core machine, a SAC update of
    the 256x256 networks takes 11 ms on 1 thread, and 460 ms on 2 threads when another process
    holds a core (OpenMP threads spin-waiting on each other); on an idle machine 2 threads gain
    little at these sizes."""
    stop_at_success: float | None = None
    """Stop early once a periodic evaluation reaches this success rate (None: never)."""
    teacher_fraction: float = 0.0
    """Beyond the paper: the probability, at the start of training, that a training episode is
    driven by the RRT planner with the full scene model (`clamgen.baselines.rrt.RRTPolicy`)
    instead of the agent. Its transitions go into the replay like any other (demonstrations for
    the off-policy learner); evaluation always uses the agent. 0: never (the paper)."""
    teacher_until: float = 1.0
    """Fraction of training at which the teacher's probability has decreased linearly from
    `teacher_fraction` to 0 (afterwards the agent drives every episode)."""

    def __post_init__(self) -> None:
        _require_int("loop.total_env_steps", self.total_env_steps, 1)
        if not (_is_number(self.teacher_fraction) and 0 <= self.teacher_fraction <= 1):
            raise ValueError(
                f"loop.teacher_fraction must be in [0, 1], got {self.teacher_fraction}"
            )
        if not (_is_number(self.teacher_until) and 0 < self.teacher_until <= 1):
            raise ValueError(f"loop.teacher_until must be in (0, 1], got {self.teacher_until}")
        _require_int("loop.learning_starts", self.learning_starts, 0)
        # `not x >= 0` also refuses NaN, which every comparison calls False.
        if not (_is_number(self.updates_per_step) and 0 <= self.updates_per_step < np.inf):
            raise ValueError(
                f"loop.updates_per_step must be a finite number >= 0, got {self.updates_per_step}"
            )
        for name in ("eval_every_steps", "checkpoint_every_steps", "log_every_steps"):
            _require_int(f"loop.{name}", getattr(self, name), 0)
        _require_int("loop.num_eval_episodes", self.num_eval_episodes, 1)
        _require_int("loop.torch_threads", self.torch_threads, 1)
        target = self.stop_at_success
        if target is not None and not (_is_number(target) and 0 <= target <= 1):
            raise ValueError(f"loop.stop_at_success must be in [0, 1] or None, got {target}")
        check_training_seed(self.seed)  # never a validation or test seed

    def teacher_probability(self, progress: float) -> float:
        """Probability that an episode starting at `progress` (fraction of the budget done) is
        driven by the teacher."""
        return self.teacher_fraction * max(0.0, 1.0 - progress / self.teacher_until)


@dataclass(frozen=True)
class TrainConfig:
    """Everything `clamgen train` needs; written as JSON into every run directory."""

    run_dir: Path = Path("runs/base")
    """Directory for config, metrics, TensorBoard events and checkpoints."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """Environment settings."""
    agent: SACConfig = field(default_factory=SACConfig)
    """SAC settings."""
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    """Replay buffer and hindsight relabelling settings."""
    loop: LoopConfig = field(default_factory=LoopConfig)
    """Training loop settings."""


# ---------------------------------------------------------------- (de)serialisation
_SCHEDULES = {"linear_ramp": LinearRamp, "constant": Constant}


def to_jsonable(config: Any) -> Any:
    """A dataclass config as JSON-compatible data (schedules tagged with their kind)."""
    if dataclasses.is_dataclass(config):
        data = {f.name: to_jsonable(getattr(config, f.name)) for f in dataclasses.fields(config)}
        for kind, cls in _SCHEDULES.items():
            if type(config) is cls:
                data = {"kind": kind, **data}
        return data
    if isinstance(config, Path):
        return str(config)
    if isinstance(config, tuple | list):
        return [to_jsonable(v) for v in config]
    return config


def from_dict(cls: type, data: dict[str, Any], where: str = "") -> Any:
    """Build dataclass `cls` from (possibly partial) nested data; unknown keys are errors, and so
    are values of the wrong type (a ValueError naming the field, the value and the type wanted).
    `where` is the dotted name of `data` inside the outermost config ("" for that one)."""
    if not isinstance(data, dict):
        raise ValueError(f"{where or cls.__name__} must be a table of fields, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ValueError(
            f"unknown {cls.__name__} fields {sorted(unknown)}"
            f"{f' in {where}' if where else ''}; known: {sorted(names)}"
        )
    kwargs = {}
    for name, value in data.items():
        kwargs[name] = _convert(hints[name], value, f"{where}.{name}" if where else name)
    try:
        return cls(**kwargs)
    except _FieldError:
        raise
    except ValueError as error:  # from __post_init__: say where, unless it already does
        message = str(error)
        if where and not message.startswith(f"{where}."):
            message = f"{where}: {message}"
        raise _FieldError(message) from error


class _FieldError(ValueError):
    """A bad value inside nested config data, its message already naming the field."""


def _convert(hint: Any, value: Any, where: str) -> Any:
    if hint is Schedule or (
        typing.get_origin(hint) is not None and LinearRamp in typing.get_args(hint)
    ):
        if _is_number(value):
            return Constant(float(value))
        if not isinstance(value, dict):
            raise _FieldError(
                f"{where} = {value!r}: expected a number or a schedule table with kind in "
                f"{sorted(_SCHEDULES)}"
            )
        data = dict(value)
        kind = data.pop("kind", None)
        if kind not in _SCHEDULES:
            raise _FieldError(f"{where}: schedule needs kind in {sorted(_SCHEDULES)}, got {kind!r}")
        return from_dict(_SCHEDULES[kind], data, where)
    if dataclasses.is_dataclass(hint):
        return from_dict(hint, value, where)
    try:
        return _typed(hint, value)
    except TypeError:
        raise _FieldError(f"{where} = {value!r}: expected {_describe(hint)}") from None


def _typed(hint: Any, value: Any) -> Any:
    """`value` as type `hint` (a list for a tuple, a string for a Path, an integer for a float);
    a TypeError if it is not of that type. Hints other than those of config fields pass."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is type(None):
        if value is not None:
            raise TypeError
        return None
    if hint is bool:
        if not isinstance(value, bool | np.bool_):
            raise TypeError
        return bool(value)
    if hint is int:
        if not isinstance(value, int | np.integer) or isinstance(value, bool):
            raise TypeError
        return int(value)
    if hint is float:
        if not _is_number(value):
            raise TypeError
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise TypeError
        return value
    if hint is Path:
        if not isinstance(value, str | Path):
            raise TypeError
        return Path(value)
    if origin is Literal:
        for choice in args:
            if value == choice and type(value) is type(choice):
                return value
        raise TypeError
    if origin in (typing.Union, types.UnionType):
        for option in args:
            try:
                return _typed(option, value)
            except TypeError:
                continue
        raise TypeError
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise TypeError
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_typed(args[0], v) for v in value)
        if len(value) != len(args):
            raise TypeError
        return tuple(_typed(a, v) for a, v in zip(args, value, strict=True))
    return value


def _describe(hint: Any) -> str:
    """What a value of type `hint` is, in words ("an integer", "a list of 2 numbers")."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    names = {
        bool: "true or false",
        int: "an integer",
        float: "a number",
        str: "a string",
        Path: "a path (a string)",
        type(None): "none",
    }
    if hint in names:
        return names[hint]
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_plural(args[0])}"
        if len(set(args)) == 1:
            return f"a list of {len(args)} {_plural(args[0])}"
        return "a list of " + ", ".join(_describe(a) for a in args)
    return getattr(hint, "__name__", str(hint))


def _plural(hint: Any) -> str:
    return {int: "integers", float: "numbers", str: "strings", bool: "booleans"}.get(
        hint, f"values ({_describe(hint)})"
    )


def parse_assignments(cls: type, items: Iterable[str]) -> dict[str, Any]:
    """A command line's `FIELD=VALUE` strings (`--set`) as {field: value} for the top-level
    fields of dataclass `cls`. VALUE is read as a TOML value where it is one (`3`, `0.5`,
    `true`, `"text"`, `[2, 1]`) and as a bare string otherwise (`absolute`), then checked
    against the field's type as a preset's value is. A ValueError with a one-line message for
    an item without `=` or a value, an unknown field, or a value of the wrong type."""
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    changes = {}
    for item in items:
        name, equals, text = item.partition("=")
        if not equals or not text:
            raise ValueError(f"{item!r} is not FIELD=VALUE")
        if name not in names:
            raise ValueError(f"{name!r} is not a {cls.__name__} field; known: {', '.join(names)}")
        try:
            value = tomllib.loads(f"value = {text}")["value"]
        except tomllib.TOMLDecodeError:
            value = text
        changes[name] = _convert(hints[name], value, name)
    return changes


def config_to_json(config: TrainConfig) -> str:
    return json.dumps(to_jsonable(config), indent=2)


def config_from_json(text: str, cls: type = TrainConfig) -> Any:
    return from_dict(cls, json.loads(text))


def resolve_preset(name_or_path: str) -> Path:
    """A preset file: a path, or the name of a file in `clamgen/presets/` (without .toml)."""
    path = Path(name_or_path)
    if path.suffix == ".toml" and path.exists():
        return path
    candidate = PRESET_DIR / f"{name_or_path}.toml"
    if candidate.exists():
        return candidate
    known = sorted(p.stem for p in PRESET_DIR.glob("*.toml"))
    raise FileNotFoundError(f"no preset {name_or_path!r}; known presets: {known}, or a .toml path")


def load_preset(name_or_path: str, cls: type = TrainConfig) -> Any:
    """The config (`cls`, e.g. TrainConfig) of a preset file; missing fields keep defaults."""
    path = resolve_preset(name_or_path)
    try:
        with path.open("rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"preset {path}: TOML syntax error: {error}") from error
    try:
        return from_dict(cls, data)
    except ValueError as error:
        raise ValueError(f"preset {path}: {error}") from error
