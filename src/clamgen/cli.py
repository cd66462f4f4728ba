"""The `clamgen` command line: one subcommand per job (`clamgen --help` lists them)."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import importlib
import json
import shlex
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, make_dataclass
from importlib.resources import files
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro

from clamgen.envs import ENV_IDS
from clamgen.experiments.policies import (
    BASELINES,
    DEPTH_RRT_BASELINES,
    SHIPPED_POLICIES,
    PolicyName,
    policy_label,
)
from clamgen.experiments.stall import ESCAPES_BEFORE_PLAN

DESCRIPTION = "CLAMGen: closed-loop UR5 arm motion generation via multi-view vision-based RL."
# Training presets shipped in clamgen/presets/, by name (`--preset NAME`).
PRESET_NAMES = tuple(
    sorted(
        p.name[: -len(".toml")]
        for p in (files("clamgen") / "presets").iterdir()
        if p.name.endswith(".toml")
    )
)
PresetName = Literal[PRESET_NAMES]  # built from the files, so `--help` lists what is shipped
EnvId = Literal[ENV_IDS]
POLICIES_HELP = (
    f"Shipped policies: {', '.join(SHIPPED_POLICIES)}; baselines: {', '.join(BASELINES)}; "
    "or the path of a policy file from `clamgen train` / `clamgen train-residual`."
)
PRESETS_HELP = f"Presets: {', '.join(PRESET_NAMES)} (clamgen/presets/), or a .toml path."


def describe_machine() -> str:
    """The CPU an evaluation ran on (`clamgen.experiments.machine`; imports torch)."""
    from clamgen.experiments.machine import describe

    return describe()


def _check_task_seed(seed: int) -> None:
    """`experiments.config.check_task_seed`, as a one-line SystemExit."""
    from clamgen.experiments.config import check_task_seed

    try:
        check_task_seed(seed)
    except ValueError as error:
        raise SystemExit(str(error)) from error


@dataclass(frozen=True)
class DemoConfig:
    """Render the scene from every camera and roll out the IK-interpolation policy."""

    env_id: EnvId = ENV_IDS[1]
    """Environment to roll out in."""
    num_episodes: int = 5
    """Episodes to roll out."""
    seed: int = 0
    """Seed of the first episode (episode i uses seed + i)."""
    image_size: int = 256
    """Side in pixels of each camera view in the saved picture."""
    out_dir: Path = Path("runs/demo")
    """Where the picture (`views.png`) and the rollout summary (`demo.json`) go."""


def demo(config: DemoConfig) -> dict:
    """Roll out the scripted IK-interpolation policy and save a picture of all camera views."""
    import gymnasium as gym
    import imageio.v3 as iio

    from clamgen.baselines import IKInterpolationPolicy
    from clamgen.experiments.evaluate import run_episode
    from clamgen.sim import constants as C

    if config.env_id not in ENV_IDS:
        raise SystemExit(f"unknown env_id {config.env_id!r}; choose one of {ENV_IDS}")
    if config.num_episodes < 1:
        raise SystemExit(f"--num-episodes must be >= 1, got {config.num_episodes}")
    _check_task_seed(config.seed)
    config.out_dir.mkdir(parents=True, exist_ok=True)
    env = gym.make(
        config.env_id,
        num_views=C.NUM_CAMERAS,
        image_size=config.image_size,
        obs_mode="both",
        render_mode="rgb_array",
    )
    policy = IKInterpolationPolicy()
    episodes = []
    picture = None

    def keep_first_views(obs, info, done) -> None:
        nonlocal picture
        if picture is None:  # the views of the first task, before any step
            picture = _views_picture(obs["images"], env.render())

    for i in range(config.num_episodes):
        seed = config.seed + i
        start = time.perf_counter()
        record = run_episode(env, policy, seed, on_step=keep_first_views)
        episode = {
            **record.outcome(),
            "tip_path_m": round(record.tip_path_m, 4),
            "seconds": round(time.perf_counter() - start, 3),
        }
        episodes.append(episode)
        print(
            f"episode {i}: {'success' if record.success else 'failure'} in {record.steps} "
            f"steps, tip path {record.tip_path_m:.3f} m, collision: {record.collided}"
        )
    env.close()
    picture_path = config.out_dir / "views.png"
    iio.imwrite(picture_path, picture)
    summary = {
        "env_id": config.env_id,
        "policy": "ik_interpolation",
        "success_rate": float(np.mean([e["success"] for e in episodes])),
        "episodes": episodes,
        "picture": str(picture_path),
    }
    (config.out_dir / "demo.json").write_text(json.dumps(summary, indent=2))
    print(f"success rate {summary['success_rate']:.2f} over {len(episodes)} episodes")
    print(f"camera views (RGB above depth) and the outside view: {picture_path}")
    return summary


def _views_picture(images: np.ndarray, overview: np.ndarray) -> np.ndarray:
    """One RGB picture: the views' RGB in a row, their depth below, the outside view beside."""
    rgb = np.concatenate(list(images[:, :3].transpose(0, 2, 3, 1)), axis=1)
    depth = np.concatenate(list(images[:, 3]), axis=1)
    grid = np.concatenate([rgb, np.repeat(depth[..., None], 3, axis=-1)], axis=0)
    # Resize the outside view to the grid's height by nearest-neighbour sampling.
    rows = np.linspace(0, overview.shape[0] - 1, grid.shape[0]).astype(int)
    width = round(overview.shape[1] * grid.shape[0] / overview.shape[0])
    cols = np.linspace(0, overview.shape[1] - 1, width).astype(int)
    return np.concatenate([overview[rows][:, cols], grid], axis=1)


def train(config) -> dict:
    """Train the joint-space SAC base policy with HER and reversible HER (stage 1)."""
    from clamgen.experiments.train import train as run_training

    if config.env.env_id not in ENV_IDS:
        _check_other_env(config.env)
    _check_run_dir(config.run_dir)
    summary = run_training(config)
    print(json.dumps(summary, indent=2))
    print(f"run directory: {config.run_dir} (policy: {config.run_dir / 'policy.pt'})")
    return summary


def train_residual(config) -> dict:
    """Train the stage-2 vision residual on the frozen base policy (CLAMGen, Table 2)."""
    from clamgen.experiments.stage2 import Stage2Trainer

    _check_run_dir(config.run_dir)
    _check_base_policy(config.base_policy)
    summary = Stage2Trainer(config).run()
    print(json.dumps(summary, indent=2))
    print(f"run directory: {config.run_dir} (policy: {config.run_dir / 'policy.pt'})")
    return summary


def distill(config) -> dict:
    """Distil a privileged residual into a vision residual with DAgger (beyond the paper)."""
    from clamgen.experiments.distill import distill as run_distillation

    _check_run_dir(config.student.run_dir)
    _check_base_policy(config.student.base_policy)
    summary = run_distillation(config)
    del summary["iterations"]
    print(json.dumps(summary, indent=2))
    run_dir = config.student.run_dir
    print(f"run directory: {run_dir} (policy: {run_dir / 'policy.pt'})")
    return summary


def _check_run_dir(run_dir: Path) -> None:
    """A ValueError, before anything is built or written, when `run_dir` is a file or cannot
    be written (nor created: its nearest existing parent is a file or cannot be written)."""
    existing = Path(run_dir)
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        where = "is" if existing == Path(run_dir) else f"cannot be created: {existing} is"
        raise ValueError(f"--run-dir {run_dir} {where} a file, not a directory")
    try:  # the only sure test of writability (read-only mounts, root, ACLs)
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as error:
        where = "" if existing == Path(run_dir) else f"cannot be created: {existing} "
        raise ValueError(
            f"--run-dir {run_dir} {where}is not writable ({error.strerror or error})"
        ) from error


def _check_base_policy(name: str) -> None:
    """A ValueError unless `name` is the shipped base policy or a stage-1 policy file."""
    from clamgen.experiments import checkpoint as ckpt

    path = ckpt.resolve_policy_path(name)
    if name not in SHIPPED_POLICIES and not path.is_file():
        hint = f"; its policy file is {path / 'policy.pt'}" if path.is_dir() else ""
        raise ValueError(
            f"--base-policy {name!r}: no such policy file{hint}; pass `base` (shipped) or the "
            "policy file of a `clamgen train` run (RUN_DIR/policy.pt)"
        )
    payload = ckpt.load_torch(path, kind=None)
    if payload.get("kind") != ckpt.POLICY_KIND:
        raise ValueError(
            f"--base-policy {name!r} holds a {payload.get('kind')!r}, not a stage-1 policy "
            f"({ckpt.POLICY_KIND!r}); pass `base` or the policy file of a `clamgen train` run"
        )


def _check_policy(name: str | Path) -> None:
    """A ValueError listing the valid names when `name` is neither a shipped policy, nor a
    baseline, nor an existing file; an ImportError when `rrt` or a `depth-rrt-*` baseline
    lacks its planner (OMPL)."""
    if name == "rrt" or name in DEPTH_RRT_BASELINES:
        try:
            for module in ("ompl.base", "ompl.geometric"):
                importlib.import_module(module)
        except ImportError as error:
            raise ImportError(
                f"--policy {name} needs OMPL 2 (`pip install ompl`, or clamgen[planning])"
            ) from error
    if name in (*SHIPPED_POLICIES, *BASELINES) or Path(name).is_file():
        return
    hint = f" ({name} is a directory; its policy file is {Path(name) / 'policy.pt'})"
    raise ValueError(
        f"--policy {str(name)!r} not found{hint if Path(name).is_dir() else ''}; choose one of "
        f"{', '.join((*SHIPPED_POLICIES, *BASELINES))}, or the path of a policy file "
        "(RUN_DIR/policy.pt from `clamgen train` / `clamgen train-residual`)"
    )


def _refuse_to_overwrite(stem: Path, suffixes: tuple[str, ...], overwrite: bool) -> None:
    """`outputs.check_output_stem`: a FileExistsError when an output `stem` + suffix exists
    and `overwrite` is False; SystemExit for a stem with a stray suffix."""
    from clamgen.experiments.outputs import check_output_stem

    try:
        check_output_stem(stem, suffixes, overwrite)
    except ValueError as error:
        raise SystemExit(str(error)) from error


def _option_value(argv: list[str], flag: str) -> str | None:
    """The value given to `flag` (`FLAG VALUE` or `FLAG=VALUE`, the last one wins), or None."""
    value = None
    for i, arg in enumerate(argv):
        if arg == flag:
            if i + 1 >= len(argv) or argv[i + 1].startswith("--"):
                raise SystemExit(f"{flag} needs a value")
            value = argv[i + 1]
        elif arg.startswith(flag + "="):
            value = arg[len(flag) + 1 :]
    return value


def _train_config(argv: list[str], default_preset: str = "base", stage: int = 1):
    """A config from `--preset NAME` plus command-line overrides.

    The preset is read first (it sets every default that `--help` shows); the command line is
    then parsed against those defaults, with `--preset` itself among the listed options.
    """
    from clamgen.experiments.config import TrainConfig, load_preset
    from clamgen.experiments.stage2 import Stage2Config

    cls = TrainConfig if stage == 1 else Stage2Config
    handler = {1: train, 2: train_residual, 3: distill}[stage]
    preset = _option_value(argv, "--preset") or default_preset
    try:
        default = load_preset(preset, cls)
    except (FileNotFoundError, ValueError) as error:
        raise SystemExit(str(error)) from error
    preset_help = f"Preset the options below start from. {PRESETS_HELP}"
    if stage == 3:  # the student's stage-2 config, then the DAgger settings
        from clamgen.experiments.distill import DistillSettings

        distill_fields = [("distill", DistillSettings, field(default_factory=DistillSettings))]
    command = make_dataclass(
        f"{cls.__name__}Command",
        [
            (
                "preset",
                Annotated[PresetName | Path, tyro.conf.arg(help=preset_help)],
                field(default=preset if preset in PRESET_NAMES else Path(preset)),
            ),
            ("config", Annotated[cls, tyro.conf.arg(name="")], field(default=default)),
            *(distill_fields if stage == 3 else ()),
        ],
        frozen=True,
    )
    name = {1: "train", 2: "train-residual", 3: "distill"}[stage]
    other_envs = OTHER_ENVS_HELP if stage == 1 else ""
    parsed = tyro.cli(
        command,
        args=argv,
        prog=f"clamgen {name}",
        description=f"{handler.__doc__} Options start from --preset {preset!r}. {PRESETS_HELP}"
        f"{other_envs}",
    )
    if stage == 3:
        from clamgen.experiments.distill import DistillConfig

        return DistillConfig(student=parsed.config, distill=parsed.distill)
    return parsed.config


OTHER_ENVS_HELP = (
    " --env.env-id also takes any goal-conditioned Gymnasium env (a Dict observation with "
    "observation, achieved_goal and desired_goal, and compute_reward), as MODULE:ID to import "
    "the module that registers it first: --env.env-id panda_gym:PandaReach-v3 (pip install "
    "panda-gym). Such an env logs no collision rate or tip path (it provides neither), and "
    "`clamgen eval` / `clamgen render` run the policy on that env."
)
# EnvConfig fields that only CLAMGen envs read (value at which another env ignores them).
CLAMGEN_ENV_OPTIONS = {
    "target_speed": 0.0,
    "num_views": 0,
    "obs_mode": "joints",
    "include_obstacle_state": False,
    "previous_action": False,
}


def _check_other_env(env_config) -> None:
    """One line, before any training, when another env cannot be made or is given options
    only CLAMGen envs have."""
    from clamgen.experiments.evaluate import make_goal_env

    for name, neutral in CLAMGEN_ENV_OPTIONS.items():
        if getattr(env_config, name) != neutral:
            flag = "--env." + name.replace("_", "-")
            raise SystemExit(f"{flag} applies to CLAMGen envs only, not {env_config.env_id!r}")
    try:
        make_goal_env(env_config.env_id).close()
    except ValueError as error:
        raise SystemExit(str(error)) from error


@dataclass(frozen=True)
class EvalConfig:
    """Reproduce a row set of the paper's Table 1 (reaching) or Table 2 (obstacles)."""

    table: Literal[1, 2] = 1
    """1: static and moving targets, no obstacles; 2: static targets past two obstacles, on the
    standard obstacle tasks and on the blocked-path tasks."""
    policy: PolicyName | Path = "base"
    """A policy shipped with the package (`base`; the vision residuals `residual-3views`,
    `residual-2views`, `residual-1view`; `image-only`), a baseline
    (`ik`: IK interpolation, `rrt`: RRT-Connect with the full scene model,
    `depth-rrt-3views` / `-2views` / `-1view`: RRT-Connect on the depth map of that many
    rendered views, no learned policy, beyond the paper), or a policy file written by
    `clamgen train` / `clamgen train-residual` (`RUN_DIR/policy.pt`)."""
    num_tasks: int = 200
    """Evaluation tasks per speed row, or per task family of Table 2 (the paper: 200)."""
    first_seed: int = 1_000_000_000
    """Seed of the first task (task i: first_seed + i). Tables take test seeds only
    (`clamgen.experiments.config.TEST_SEEDS`); validation seeds are refused."""
    families: tuple[str, ...] = ("obstacles", "blocked")
    """Table 2 task families: `obstacles` (CLAMGen/ReachObstacles-v0), `blocked`
    (CLAMGen/ReachBlocked-v0: the obstacle-blind path collides)."""
    speeds: tuple[str, ...] = ("0", "0.05", "0.1", "0.2", "variable")
    """Target speeds in m/s, or `variable`, one table row each (Table 1)."""
    target_speed: float = 0.0
    """Table 2: the target's speed in m/s (0: static, as in the paper). A moving target among
    the obstacles is beyond the paper: the row's name says the speed, and the paper's numbers
    are not set beside it."""
    real_time: bool = False
    """Table 2: acting takes simulated time (beyond the paper; as in the paper, by default it
    takes none): an act longer than the 50 ms control period holds the arm still a step for
    each whole period it took, the target moving on (a planner's plans; the learned policies
    act in about a millisecond). The row's name says it, its JSON has the held steps per task.
    Depends on the machine's speed."""
    depth_noise_m: float = 0.0
    """Table 2: every depth pixel the policy and its depth wrapper read gets Gaussian noise of
    standard deviation `depth_noise_m * z**2` at depth z (m), drawn afresh each frame (about
    0.0015 for a Kinect v1, 0.01 for a RealSense D435's 2% at 2 m; `ReachEnv(depth_noise_m=)`,
    beyond the paper). The same tasks; the row's name says it. 0: exact depth."""
    out: Path | None = None
    """Output stem: writes OUT.json and OUT.md (default: runs/eval/table<N>_<policy>, the
    policy's name or, for RUN_DIR/policy.pt, the run directory's)."""
    overwrite: bool = False
    """Replace OUT.json and OUT.md if they exist (otherwise an existing result is kept and
    nothing is evaluated)."""
    name: str | None = None
    """Table 2 row name (default: from the policy)."""
    torch_threads: int = 1
    """Torch CPU threads for acting. One is fastest for batch-1 inference of these networks,
    and more are much slower while other jobs share the cores."""
    lookahead_candidates: int = 0
    """> 0: a privileged residual plans before each step with rollouts of itself in a copy of
    the simulator, this many perturbed plans when its own does not arrive cleanly
    (`clamgen.experiments.lookahead`, the distillation teacher). It then uses the true scene,
    like RRT with the full model. 0: the policy alone."""
    lookahead_margin_m: float = 0.0
    """With --lookahead-candidates: the clearance (m) its plans keep from obstacles and the
    table where they can (0: true contact)."""
    depth_hybrid: bool = False
    """A vision residual acts as Table 2's hybrid rows: through the depth shield at 1 cm with the
    planner when stuck, both reading 128-pixel depth cameras at the views' poses, and from one view
    keeping the hand out of unseen space within 5 cm behind seen surfaces, the planner meeting a
    moving target (`clamgen.experiments.depth_planner.HYBRID`, beyond the paper; the settings chosen
    on validation tasks). Not with the other --depth-* options but --depth-plan-checks and
    --depth-track-m, which set its planner's, and --depth-noise-model-m. From one view
    --depth-escapes --depth-planner does better on the blocked tasks
    (`results/stage2/ensemble/aims.md`)."""
    depth_shield_m: float | None = None
    """A vision policy acts through the collision shield on its own depth images, keeping this
    clearance (m; 0.01 was chosen on validation tasks) from the obstacle surface it has seen
    and the table (`clamgen.experiments.depth_shield`, beyond the paper). Off by default."""
    depth_planner: bool = False
    """With --depth-shield-m: when the policy stops making progress towards the target, plan a
    path on the depth map it has seen with RRT-Connect and follow it
    (`clamgen.experiments.depth_planner`, beyond the paper; needs OMPL)."""
    depth_shadow_m: float | None = None
    """With --depth-shield-m: the hand also keeps out of the space the arm has hidden from the
    cameras since the episode began, where it lies within this distance (m; 0.05 with
    --depth-shadow-behind-surfaces was chosen on 1-view validation tasks) of obstacle surface
    seen so far (`clamgen.experiments.depth_shield.ArmShadow`). Off by default."""
    depth_shadow_behind_surfaces: bool = False
    """With --depth-shadow-m: space hidden behind any surface the cameras see (obstacles'
    unseen sides too), not only behind the arm, counts as hidden."""
    depth_bridge_m: float = 0.0
    """With --depth-shield-m: neighbouring pixels' obstacle points up to this far apart (m)
    are joined by surface on the depth map, so that a side seen at a grazing angle is not
    left sparse (`clamgen.experiments.depth_shield.DepthOccupancy`, beyond the paper; 0.05
    on 1-view validation tasks changed nothing measurable). 0: off."""
    depth_fine_size: int = 0
    """With --depth-shield-m: the shield reads the views' depth from a finer depth camera at
    the same poses, rendered at this many pixels a side (`ReachEnv(fine_depth_size=...)`, an
    extra sensor, beyond the paper); the policy still acts on its own images. 0: the
    policy's own images."""
    depth_plan_checks: int = 0
    """With --depth-planner or --depth-hybrid (or a `depth-rrt-*` baseline): each plan may spend
    this many validity checks instead of 1 s, so that the episodes do not depend on the machine's
    speed or load (about 10,000 checks a second on one core here;
    `depth_planner.DepthShieldPlanner`). 0: the time budget."""
    depth_track_m: float | None = None
    """With --depth-planner or --depth-hybrid (or a `depth-rrt-*` baseline): plan to meet a moving
    target where its observed velocity takes it, planning again when it is this far (m) off the
    course planned for (`depth_planner.DepthShieldPlanner`, beyond the paper; a static target is
    planned for the same either way). 0: plan to where the target is. Default: 0.02 for the
    `depth-rrt-*` baselines and --depth-hybrid (chosen on validation tasks), else 0."""
    depth_noise_model_m: float = 0.0
    """With a depth wrapper (or a `depth-rrt-*` baseline): its map is told the depth cameras'
    noise model, sd this times z**2 at depth z (m; as --depth-noise-m), and takes a point
    within 3 sds along its ray of the arm, the table or the target for it
    (`depth_shield.DepthOccupancy`, beyond the paper). 0: exact depth assumed."""
    depth_goal_zone_m: float = 0.0
    """With --depth-planner or --depth-hybrid: where no configuration at the goal keeps the
    margin from the depth map, plan to it keeping 3 mm within this distance (m) of the target
    and the margin elsewhere, and let the shield keep 3 mm while the arm follows a plan there
    (`depth_planner.DepthShieldPlanner`, beyond the paper). 0: such goals are not planned to."""
    depth_escapes: bool = False
    """Instead of --depth-planner: once the episode has stalled 10 steps, 5 steps of one random
    joint command, then the policy again, every step through the shield, which stops an escape
    that would touch an obstacle (`stall.StallBurst`, beyond the paper): no step plans. Alone,
    the setting of Table 2's escape rows (`depth_planner.ESCAPES`: the hybrids' shield with the
    unseen-space test); with --depth-shield-m, added to the shield those options give. With
    --depth-planner too: the planner when stuck and the escapes where it finds no path
    (`depth_planner.ESCAPES_PLANNER`, alone; Table 2's 1-view row "... random escapes where
    the planner finds no path"), or the escapes first (--depth-escapes-before-plan)."""
    depth_escapes_before_plan: int = ESCAPES_BEFORE_PLAN
    """With --depth-escapes and --depth-planner: the random escapes an episode begins before the
    planner may plan (0: the planner first, chosen on validation tasks;
    `depth_planner.DepthShieldPlanner`)."""
    depth_views: int = 0
    """With the depth options, for a policy that sees no images (`base`, `ik`, a joint policy
    file): the env renders this many RGBD views (the first cameras, at the shipped residuals'
    64 pixels) for the depth wrapper alone, and the policy acts through it on what they show
    (a control for what a vision residual adds inside the wrapper). 0: the policy's own views."""
    action_scale: float = 1.0
    """The policy's actions multiplied by this, in (0, 1]: each step in the same direction and
    this much as long, a slower arm that takes more steps to reach
    (`clamgen.policy.ScaledPolicy`, beyond the paper). 1: as trained. With the depth options
    the shield checks the scaled steps (its random escapes are not scaled)."""


TABLE2_ROW_NAMES = {
    "rrt": "RRT with full model",
    "ik": "IK interpolation (no obstacle model)",
    "base": "base joint policy alone (no vision)",
    **{
        name: f"RRT on the depth map of {views} RGBD view{'s' * (views > 1)}, no learned "
        "policy (ours)"
        for name, views in DEPTH_RRT_BASELINES.items()
    },
}
GUARDED_ROW_NAMES = {"base": "base joint policy (no vision)"}
"""Table 2 row names of policies acting through a depth wrapper, where they differ from
`TABLE2_ROW_NAMES` (the wrapper's description follows)."""


def evaluate_table(config: EvalConfig) -> list:
    """Evaluate a policy on held-out tasks and print the paper's table beside ours."""
    if config.table not in (1, 2):
        raise SystemExit(f"--table must be 1 or 2, got {config.table}")
    if config.target_speed != 0 and config.table != 2:
        raise SystemExit("--target-speed is Table 2's (Table 1 takes --speeds)")
    if config.real_time and config.table != 2:
        raise SystemExit("--real-time is Table 2's")
    if config.depth_noise_m and config.table != 2:
        raise SystemExit("--depth-noise-m is Table 2's")
    _nonnegative("--depth-noise-m", config.depth_noise_m)
    from clamgen.experiments.checkpoint import CheckpointError
    from clamgen.experiments.config import check_table_seeds
    from clamgen.experiments.policies import load_policy, policy_observation
    from clamgen.experiments.tables import (
        DEPTH_RRT_TABLE1_NOTE,
        RRT_TABLE1_NOTE,
        TABLE2_FAMILIES,
        table1,
        table1_markdown,
        write_table1,
    )
    from clamgen.tasks.reach import validate_speed

    try:
        validate_speed(config.target_speed)
    except ValueError as error:
        raise SystemExit(f"bad --target-speed: {error}") from error
    if config.num_tasks < 1:
        raise SystemExit(f"--num-tasks must be >= 1, got {config.num_tasks}")
    try:
        check_table_seeds(config.first_seed, config.num_tasks)
    except ValueError as error:
        raise SystemExit(f"bad --first-seed: {error}") from error
    unknown = set(config.families) - set(TABLE2_FAMILIES)
    if unknown or not config.families:
        raise SystemExit(f"--families must be among {TABLE2_FAMILIES}, got {config.families}")
    if config.torch_threads < 1:
        raise SystemExit(f"--torch-threads must be >= 1, got {config.torch_threads}")
    import torch

    torch.set_num_threads(config.torch_threads)
    try:
        speeds = [validate_speed(s if s == "variable" else float(s)) for s in config.speeds]
    except ValueError as error:
        raise SystemExit(f"bad --speeds: {error}") from error
    try:
        _check_policy(config.policy)
    except (ValueError, ImportError) as error:
        raise SystemExit(str(error)) from error
    _check_depth_request(config)
    label = policy_label(config.policy)
    env_id = _policy_env_id(config.policy)
    out = config.out or Path("runs/eval") / f"table{config.table}_{label}"
    if env_id in ENV_IDS:  # (another env's results are named after it, and checked there)
        _refuse_to_overwrite(out, (".json", ".md"), config.overwrite)
    try:
        policy, source, env_kwargs = _load_with_depth_rrt_options(config, load_policy)
    except CheckpointError as error:
        raise SystemExit(str(error)) from error
    if config.lookahead_candidates != 0:
        policy, source = _with_lookahead(
            policy, source, config.lookahead_candidates, config.lookahead_margin_m
        )
    policy, source = _with_action_scale(policy, source, config.action_scale)
    policy_name = str(config.policy)
    row_name = TABLE2_ROW_NAMES.get(policy_name, label)  # Table 2's, without --name
    if _wants_depth_shield(config):
        plain = source
        policy, source, env_kwargs = _with_depth_shield(policy, source, env_kwargs, config)
        # The row is named after the policy and its wrapper.
        name = GUARDED_ROW_NAMES.get(policy_name) or row_name
        row_name = guarded_row_name(name, source[len(plain) :], config.depth_views)
    if env_id not in ENV_IDS:
        return _evaluate_other_env(config, policy, source, label, env_id)
    if config.table == 2:
        return _evaluate_table2(config, policy, source, row_name, out, env_kwargs)
    note = RRT_TABLE1_NOTE if config.policy == "rrt" else None
    note = DEPTH_RRT_TABLE1_NOTE if str(config.policy) in DEPTH_RRT_BASELINES else note
    if note:
        print(f"note: {note}")
    print(f"evaluating {source} on {config.num_tasks} held-out tasks per speed ...")
    rows = table1(
        policy,
        config.num_tasks,
        speeds,
        env_kwargs=env_kwargs,
        first_seed=config.first_seed,
        progress=lambda row: print(
            f"  speed {row.label():>16}: success {row.success_rate:.3f}, path ratio "
            f"{row.path_ratio:.3f}, {row.median_act_ms:.4f} ms/action"
        ),
    )
    meta = {
        "policy": source,
        "observation": policy_observation(policy),
        "num_tasks": config.num_tasks,
        "first_seed": config.first_seed,
        "command": "clamgen eval " + shlex.join(sys.argv[2:]),
        "machine": describe_machine(),
        **({"note": note} if note else {}),
    }
    write_table1(rows, out, meta)
    print()
    print(table1_markdown(rows, meta["observation"], note))
    print(f"\nwrote {out.with_suffix('.json')} and {out.with_suffix('.md')}")
    return rows


UNTOLD_NOISE_NOTE = (
    "--depth-noise-m without --depth-noise-model-m: the depth map assumes exact depth and takes "
    "noisy pixels of the arm for obstacles around it (measured: the 2-view hybrid reaches 0.635 "
    "of the blocked tasks at K = 0.0015 and none at 0.01; results/stage2/noise/README.md); "
    "add --depth-noise-model-m K to tell it the camera's noise"
)
"""Printed when a depth wrapper or a `depth-rrt-*` baseline reads noisy depth untold (the
measured "as shipped" rows do so on purpose)."""


def _wants_depth_shield(config) -> bool:
    """Whether the policy acts through a depth wrapper built from the depth shield's options
    (`clamgen eval` and `render`); a `depth-rrt-*` baseline is one already."""
    if str(config.policy) in DEPTH_RRT_BASELINES:
        return False
    return config.depth_hybrid or _depth_options_given(config)


def _check_depth_request(config) -> None:
    """SystemExit, before any policy is loaded, for --depth-views without a depth wrapper's
    options, or for a `depth-rrt-*` baseline with any depth option but --depth-plan-checks
    and --depth-track-m (it has the others' setting already)."""
    if str(config.policy) in DEPTH_RRT_BASELINES:
        others = dataclasses.replace(
            config, depth_plan_checks=0, depth_track_m=None, depth_noise_model_m=0.0
        )
        if config.depth_hybrid or _depth_options_given(others) or config.depth_views:
            raise SystemExit(
                f"--policy {config.policy} plans on the depth map of its own views through the "
                "hybrid's shield already: drop the --depth-* options (but --depth-plan-checks, "
                "--depth-track-m and --depth-noise-model-m)"
            )
        _plan_checks(config)
        _track_m(config, 0.0)
        _noise_model_m(config)
        mapped = True  # (it plans on a depth map)
    else:
        mapped = _wants_depth_shield(config)
        if config.depth_views and not mapped:
            raise SystemExit(
                "--depth-views renders views for the depth wrapper: give its options too "
                "(--depth-hybrid, --depth-escapes or --depth-shield-m)"
            )
    if mapped and config.depth_noise_m and not config.depth_noise_model_m:
        print(f"note: {UNTOLD_NOISE_NOTE}")


def _depth_options_given(config) -> bool:
    return (
        config.depth_shield_m is not None
        or config.depth_planner
        or config.depth_shadow_m is not None
        or config.depth_shadow_behind_surfaces
        or config.depth_bridge_m != 0
        or config.depth_fine_size != 0
        or config.depth_plan_checks != 0
        or config.depth_track_m is not None
        or config.depth_noise_model_m != 0
        or config.depth_goal_zone_m != 0
        or config.depth_escapes
        or config.depth_escapes_before_plan != ESCAPES_BEFORE_PLAN
    )


def _with_depth_shield(policy, source: str, env_kwargs: dict, config):
    """`policy` acting through the depth shield with `config`'s depth options (with
    --depth-hybrid, the Table 2 hybrid setting for its number of views; with --depth-planner,
    planning on the depth map when stuck; with --depth-shadow-m, keeping the hand out of the
    arm's shadow near seen obstacle surface, or with --depth-shadow-behind-surfaces out of any
    surface's; with --depth-bridge-m, joining neighbouring pixels' surface; with
    --depth-fine-size, reading a finer depth camera), its source, and the env's options with
    what the shield needs added; SystemExit unless it observes its joints and depth images
    and, with any other depth option, a margin is given."""
    from importlib.util import find_spec

    from clamgen.experiments.depth_planner import ESCAPES, ESCAPES_PLANNER, HYBRID

    # A preset takes --depth-plan-checks, --depth-track-m and --depth-goal-zone-m for its
    # planner, and --depth-noise-model-m; the rest it sets.
    planning = dataclasses.replace(
        config,
        depth_plan_checks=0,
        depth_track_m=None,
        depth_noise_model_m=0.0,
        depth_goal_zone_m=0.0,
    )
    if config.depth_hybrid and _depth_options_given(planning):
        raise SystemExit(
            "--depth-hybrid sets the depth options itself: drop the others (but "
            "--depth-plan-checks, --depth-track-m, --depth-goal-zone-m and "
            "--depth-noise-model-m)"
        )
    # --depth-escapes without a shield's options (with --depth-planner or not): the escape
    # rows' shield.
    escapes_alone = config.depth_escapes and not _depth_options_given(
        dataclasses.replace(
            planning,
            depth_escapes=False,
            depth_planner=False,
            depth_escapes_before_plan=ESCAPES_BEFORE_PLAN,
        )
    )
    preset = HYBRID if config.depth_hybrid else None
    if escapes_alone:
        first = _escapes_first(config)
        preset = ESCAPES
        if config.depth_planner:
            preset = {
                views: dataclasses.replace(guard, escapes_before_plan=first)
                for views, guard in ESCAPES_PLANNER.items()
            }
    guard = None if preset else _depth_guard(config)
    env_kwargs = depth_views_env(env_kwargs, config.depth_views)
    views = env_kwargs["num_views"]
    guard = guard or _preset_options(preset[min(views, max(preset))], config)
    if guard.planner and find_spec("ompl") is None:
        raise SystemExit("--depth-planner needs OMPL 2 (`pip install ompl`, or clamgen[planning])")
    try:
        shielded, env_kwargs = guard.around(policy, env_kwargs)
    except ValueError as error:
        raise SystemExit(f"bad --depth-shield-m: {error}") from error
    return shielded, source + guard.describe(), env_kwargs


def guarded_row_name(name: str, wrapper: str, depth_views: int) -> str:
    """A Table 2 row name for policy `name` acting through the depth wrapper `wrapper` (its
    `DepthGuard.describe()`), saying how many views `--depth-views` rendered for it."""
    if not depth_views:
        return name + wrapper
    return f"{name}{wrapper}, {depth_views} view{'s' * (depth_views > 1)} rendered for it"


def depth_views_env(env_kwargs: dict, depth_views: int) -> dict:
    """The env options under the depth wrapper: the policy's own, or for a policy that sees no
    images `depth_views` rendered views for the wrapper alone (`--depth-views`); SystemExit
    where neither gives it joints and RGBD views."""
    from clamgen.sim.constants import NUM_CAMERAS

    views = env_kwargs.get("num_views", 0)
    if not 0 <= depth_views <= NUM_CAMERAS:
        raise SystemExit(f"--depth-views must be in 0..{NUM_CAMERAS}, got {depth_views}")
    if views and env_kwargs.get("obs_mode") == "both":
        if depth_views not in (0, views):
            raise SystemExit(
                f"--depth-views {depth_views}: this policy acts on its own {views} view(s), "
                "which the depth wrapper reads; drop --depth-views"
            )
        return env_kwargs
    if views or not depth_views:
        raise SystemExit(
            "the depth shield needs a vision residual (a policy that observes its joints and "
            "RGBD views), or --depth-views V for a policy that sees no images"
        )
    from clamgen.experiments.depth_planner import rendered_views_env

    return env_kwargs | rendered_views_env(depth_views)


def _depth_guard(config):
    """The `DepthGuard` of `config`'s --depth-* options; SystemExit for a bad combination."""
    from clamgen.envs.reach_env import MAX_IMAGE_SIZE
    from clamgen.experiments.depth_planner import DepthGuard

    margin_m, planner = config.depth_shield_m, config.depth_planner
    shadow_m, behind_surfaces = config.depth_shadow_m, config.depth_shadow_behind_surfaces
    bridge_m, checks = config.depth_bridge_m, _plan_checks(config)
    if checks != 0 and not planner:
        raise SystemExit("--depth-plan-checks needs --depth-planner (the planner it budgets)")
    track_m = _track_m(config, 0.0)
    if config.depth_track_m is not None and not planner:
        raise SystemExit("--depth-track-m needs --depth-planner (the planner it steers)")
    goal_zone_m = _goal_zone_m(config)
    if goal_zone_m and not planner:
        raise SystemExit("--depth-goal-zone-m needs --depth-planner (the planner it relaxes)")
    escapes_first = _escapes_first(config)
    if margin_m is None:
        if shadow_m is not None or behind_surfaces:
            raise SystemExit("--depth-shadow-m needs --depth-shield-m (the shield it adds to)")
        if bridge_m != 0:
            raise SystemExit("--depth-bridge-m needs --depth-shield-m (the map it adds to)")
        if config.depth_fine_size != 0:
            raise SystemExit("--depth-fine-size needs --depth-shield-m (the shield that reads it)")
        if config.depth_noise_model_m != 0 and not planner:
            raise SystemExit(
                "--depth-noise-model-m needs a depth wrapper (--depth-hybrid, --depth-escapes or "
                "--depth-shield-m): the map it tells"
            )
        raise SystemExit("--depth-planner needs --depth-shield-m (the margin it plans with)")
    if shadow_m is not None and not 0 < shadow_m < float("inf"):
        raise SystemExit(f"--depth-shadow-m must be a number > 0, got {shadow_m}")
    if behind_surfaces and shadow_m is None:
        raise SystemExit("--depth-shadow-behind-surfaces needs --depth-shadow-m")
    _nonnegative("--depth-bridge-m", bridge_m)
    fine = config.depth_fine_size
    if fine != 0 and not 8 <= fine <= MAX_IMAGE_SIZE:
        raise SystemExit(f"--depth-fine-size must be 0 or 8..{MAX_IMAGE_SIZE}, got {fine}")
    return DepthGuard(
        margin_m,
        planner,
        shadow_m,
        behind_surfaces,
        bridge_m,
        fine,
        checks,
        config.depth_escapes,
        escapes_first,
        track_m=track_m,
        noise_m=_noise_model_m(config),
        goal_zone_m=goal_zone_m,
    )


def _plan_checks(config) -> int:
    """`config`'s --depth-plan-checks; SystemExit when it is negative."""
    if config.depth_plan_checks < 0:
        raise SystemExit(f"--depth-plan-checks must be >= 0, got {config.depth_plan_checks}")
    return config.depth_plan_checks


def _track_m(config, default: float) -> float:
    """`config`'s --depth-track-m, or `default` where it is not given; SystemExit when it is
    negative or not finite."""
    track_m = config.depth_track_m
    return default if track_m is None else _nonnegative("--depth-track-m", track_m)


def _escapes_first(config) -> int:
    """`config`'s --depth-escapes-before-plan; SystemExit when it has nothing to order."""
    first = config.depth_escapes_before_plan
    if first != ESCAPES_BEFORE_PLAN and not (config.depth_escapes and config.depth_planner):
        raise SystemExit(
            "--depth-escapes-before-plan needs --depth-escapes and --depth-planner (the two ways "
            "out of a stall it orders)"
        )
    if first < 0:
        raise SystemExit(f"--depth-escapes-before-plan must be >= 0, got {first}")
    return first


def _with_action_scale(policy, source: str, scale: float):
    """`policy` with its actions multiplied by `scale` (itself at 1), and its source;
    SystemExit for a scale outside (0, 1]."""
    if scale == 1.0:
        return policy, source
    from clamgen.policy import ScaledPolicy

    try:
        return ScaledPolicy(policy, scale), f"{source}, actions scaled by {scale:g}"
    except ValueError as error:
        raise SystemExit(f"bad --action-scale: {error}") from error


def _load_with_depth_rrt_options(config, load) -> tuple:
    """`load(config.policy)` (a `load_policy`); a `depth-rrt-*` baseline with
    --depth-plan-checks N, --depth-track-m M or --depth-noise-model-m K is built with plans of
    N validity checks (the same plans on any machine), tracking a moving target at M, or its
    map told the noise model K, its source saying so (`_depth_rrt_options`)."""
    changes = _depth_rrt_options(config)
    if str(config.policy) not in DEPTH_RRT_BASELINES or not changes:
        return load(config.policy)
    from clamgen.experiments.depth_planner import TRACK_M
    from clamgen.experiments.policies import load_policy

    policy, source, env_kwargs = load_policy(
        config.policy,
        plan_checks=config.depth_plan_checks,
        track_m=_track_m(config, TRACK_M),
        noise_m=_noise_model_m(config),
    )
    return policy, source + changes, env_kwargs


def _depth_rrt_options(config) -> str:
    """What a `depth-rrt-*` baseline's --depth-plan-checks and --depth-track-m change, as its
    source and row name say it ("" for neither)."""
    text = f", {config.depth_plan_checks} checks a plan" if config.depth_plan_checks else ""
    track_m = config.depth_track_m
    if track_m == 0:
        text += ", planning to where the target is"
    elif track_m is not None:
        text += f", replanning {track_m:g} m off a moving target's course"
    if config.depth_noise_model_m:
        text += f", depth noise model sd {config.depth_noise_model_m:g}*z^2 m"
    return text


def _with_lookahead(policy, source: str, candidates: int, margin_m: float = 0.0):
    """`policy` planning with `candidates` lookahead rollouts keeping clearance `margin_m`;
    SystemExit unless it is a privileged residual."""
    from clamgen.experiments.lookahead import LookaheadPolicy, LookaheadTeacher

    if candidates < 0:
        raise SystemExit(f"--lookahead-candidates must be >= 0, got {candidates}")
    _nonnegative("--lookahead-margin-m", margin_m)
    config = getattr(getattr(policy, "agent", None), "config", None)
    if getattr(config, "obs_source", None) != "obstacles":
        raise SystemExit(
            "--lookahead-candidates needs a privileged residual (agent.obs_source 'obstacles'), "
            f"got {source}"
        )
    teacher = LookaheadTeacher(
        policy.agent, num_obstacles=2, candidates=candidates, margin_m=margin_m
    )
    clearance = f", {margin_m * 100:g} cm clearance" if margin_m else ""
    return LookaheadPolicy(teacher), f"{source} with lookahead ({candidates} candidates{clearance})"


def _evaluate_other_env(config: EvalConfig, policy, source, label: str, env_id: str) -> dict:
    """A policy trained on another goal env, evaluated on that env's own tasks (Tables 1 and 2
    are CLAMGen tasks): success rate and what else the env provides, on test seeds."""
    from clamgen.experiments.evaluate import (
        check_policy_fits,
        evaluate,
        make_goal_env,
        summarize,
    )

    out = config.out or Path("runs/eval") / f"{label}_{_env_name(env_id)}"
    _refuse_to_overwrite(out, (".json", ".md"), config.overwrite)
    try:
        env = make_goal_env(env_id)
        check_policy_fits(policy, env, env_id)
    except ValueError as error:
        raise SystemExit(f"cannot evaluate {source}: {error}") from error
    print(
        f"{source} was trained on {env_id}; Tables 1 and 2 are CLAMGen tasks, so it is "
        f"evaluated on {config.num_tasks} tasks of {env_id} (seeds from {config.first_seed})"
    )
    seeds = config.first_seed + np.arange(config.num_tasks)
    summary = summarize(evaluate(env, policy, seeds))
    env.close()
    result = {
        "policy": source,
        "env_id": env_id,
        "num_tasks": config.num_tasks,
        "first_seed": config.first_seed,
        "command": "clamgen eval " + shlex.join(sys.argv[2:]),
        "machine": describe_machine(),
        **summary,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=2))
    rows = [f"| {key} | {value:.4g} |" for key, value in summary.items()]
    table = "\n".join([f"{source} on {env_id}", "", "| metric | value |", "|---|---|", *rows])
    out.with_suffix(".md").write_text(table + "\n")
    print(table)
    print(f"\nwrote {out.with_suffix('.json')} and {out.with_suffix('.md')}")
    return result


def _env_name(env_id: str) -> str:
    """A file-name part for an env id: `panda_gym:PandaReach-v3` -> `pandareach`."""
    return env_id.split(":")[-1].split("/")[-1].split("-")[0].lower()


def render(config) -> dict:
    """Render rollouts of a policy (learned, IK interpolation or RRT) to MP4 and GIF."""
    from clamgen.experiments.checkpoint import CheckpointError
    from clamgen.experiments.video import output_stem, render_env_rollouts, render_rollouts

    _check_depth_request(config)
    label = policy_label(config.policy)
    config = dataclasses.replace(config, out=output_stem(config, label))  # refuses to overwrite
    try:
        policy, _, env_kwargs = _load_with_depth_rrt_options(config, _load_policy)
        policy, _ = _with_action_scale(policy, "", config.action_scale)
        if _wants_depth_shield(config):
            policy, _, env_kwargs = _with_depth_shield(policy, "", env_kwargs, config)
        env_id = _policy_env_id(config.policy)
        if env_id in ENV_IDS:
            summary = render_rollouts(config, policy, label, env_kwargs)
        else:
            print(f"{label} was trained on {env_id}: rendering its rollouts there")
            summary = render_env_rollouts(config, policy, label, env_id)
    except (CheckpointError, ValueError) as error:
        raise SystemExit(str(error)) from error
    for episode in summary["episodes"]:
        print(episode)
    if summary["outcome"] != "any":
        found = len(summary["episodes"])
        tried = summary["tasks_tried"]
        print(f"{summary['outcome']}: {found} episode(s) filmed, {tried} task(s) run to find them")
    print(f"wrote {summary['mp4']} and {summary['gif']}")
    return summary


@functools.cache
def _load_policy(name: str | Path) -> tuple:
    """`experiments.policies.load_policy`, once per process (building a command's defaults
    and running it share the loaded policy); a CheckpointError for a bad policy file."""
    from clamgen.experiments.policies import load_policy

    return load_policy(name)


@functools.cache
def _policy_env_id(name: str | Path) -> str:
    """The env a policy was trained on (from its policy file's config); CLAMGen's obstacle env
    for the baselines, which need no training."""
    from clamgen.experiments import checkpoint as ckpt

    if name in BASELINES:
        return ENV_IDS[1]
    try:
        payload = ckpt.load_torch(ckpt.resolve_policy_path(name), kind=None)
        return json.loads(payload["config"])["env"]["env_id"]
    except ckpt.CheckpointError as error:
        raise SystemExit(str(error)) from error
    except (KeyError, TypeError, ValueError) as error:
        raise SystemExit(f"{name}: policy file without a training config ({error})") from error


def _policy_num_views(name: str | Path) -> int | None:
    """Camera views the policy observes (None: it observes none)."""
    from clamgen.experiments.checkpoint import CheckpointError

    try:
        _, _, env_kwargs = _load_policy(name)
    except CheckpointError as error:
        raise SystemExit(str(error)) from error
    return env_kwargs.get("num_views") or None


def _render_config(argv: list[str]):
    """Render options; `--num-views` defaults to the policy's own views (3 for policies that
    see none), so that the video shows what the policy sees."""
    from clamgen.experiments.video import RenderConfig

    name = _option_value(argv, "--policy") or RenderConfig.policy
    policy = name if name in (*SHIPPED_POLICIES, *BASELINES) else Path(name)
    if "-h" not in argv and "--help" not in argv:
        _check_policy(policy)
    default = RenderConfig(policy=policy, num_views=_policy_num_views(policy) or 3)
    return tyro.cli(
        RenderConfig,
        default=default,
        args=argv,
        prog="clamgen render",
        description=f"{render.__doc__} {POLICIES_HELP} --num-views defaults to the views the "
        "policy observes.",
    )


def _preset_options(guard, config):
    """A preset `DepthGuard` (`--depth-hybrid`, `--depth-escapes [--depth-planner]`) with
    `config`'s --depth-noise-model-m, and --depth-plan-checks and --depth-track-m for its
    planner; SystemExit where it has none."""
    checks, track_m = _plan_checks(config), _track_m(config, guard.track_m)
    goal_zone_m = _goal_zone_m(config)
    if (checks or config.depth_track_m is not None or goal_zone_m) and not guard.planner:
        raise SystemExit(
            "--depth-plan-checks, --depth-track-m and --depth-goal-zone-m need a planner "
            "(--depth-planner): --depth-escapes alone never plans"
        )
    return dataclasses.replace(
        guard,
        plan_checks=checks or guard.plan_checks,
        track_m=track_m,
        noise_m=_noise_model_m(config),
        goal_zone_m=goal_zone_m or guard.goal_zone_m,
    )


def _nonnegative(flag: str, value: float) -> float:
    """`value` of the option `flag`; SystemExit when it is negative or not finite."""
    if not 0 <= value < float("inf"):
        raise SystemExit(f"{flag} must be a number >= 0, got {value}")
    return value


def _goal_zone_m(config) -> float:
    """`config`'s --depth-goal-zone-m (`_nonnegative`)."""
    return _nonnegative("--depth-goal-zone-m", config.depth_goal_zone_m)


def _noise_model_m(config) -> float:
    """`config`'s --depth-noise-model-m (`_nonnegative`)."""
    return _nonnegative("--depth-noise-model-m", config.depth_noise_model_m)


def _table2_row_name(config: EvalConfig, name: str) -> str:
    """`--name`, else the policy's Table 2 row name `name` (with its depth wrapper's, if any)
    and what the options change: a depth-rrt baseline's options, a moving target, real
    time, depth noise."""
    if config.name:
        return config.name
    if str(config.policy) in DEPTH_RRT_BASELINES:
        name += _depth_rrt_options(config)
    if config.target_speed:
        name += f", target moving at {config.target_speed:g} m/s"
    if config.real_time:
        name += ", acting in real time"
    if config.depth_noise_m:
        name += f", depth noise sd {config.depth_noise_m:g}*z^2 m"
    return name


def _evaluate_table2(config: EvalConfig, policy, source, row_name, out: Path, env_kwargs: dict):
    """One Table 2 row name (`_table2_row_name` of `row_name`), one `ObstacleRow` per task
    family (written together)."""
    from clamgen.experiments.tables import (
        ACT_AIM_MS,
        FAMILY_TITLES,
        table2_markdown,
        table2_row,
        write_table2,
    )

    if config.target_speed:
        env_kwargs = env_kwargs | {"target_speed": config.target_speed}
    if config.depth_noise_m:
        if not env_kwargs.get("num_views"):
            raise SystemExit(
                "--depth-noise-m perturbs the views' depth: this policy observes none (give a "
                "depth wrapper --depth-views V)"
            )
        env_kwargs = env_kwargs | {"depth_noise_m": config.depth_noise_m}
    name = _table2_row_name(config, row_name)
    rows = []
    for family in config.families:
        print(f"evaluating {source} on {config.num_tasks} held-out {FAMILY_TITLES[family]} ...")
        rows.append(
            table2_row(
                name,
                policy,
                config.num_tasks,
                env_kwargs,
                family,
                config.first_seed,
                config.real_time,
            )
        )
        row = rows[-1]
        low, high = row.success_interval
        print(f"  success {row.success_rate:.3f} (95% Wilson interval {low:.3f}-{high:.3f})")
        print(
            f"  act {row.median_act_ms:.2f} ms median, {row.act_p99_ms:.1f} ms 99th percentile, "
            f"{row.act_max_ms:.1f} ms longest; {row.act_share_over_aim:.1%} of acts over "
            f"{ACT_AIM_MS:g} ms"
        )
        if row.task_held_steps is not None:
            held = sum(row.task_held_steps)
            print(f"  real time: the arm held still {held} steps in all while the policy acted")
    meta = {
        "policy": source,
        "num_tasks": config.num_tasks,
        "first_seed": config.first_seed,
        "command": "clamgen eval " + shlex.join(sys.argv[2:]),
        "machine": describe_machine(),
    }
    write_table2(rows, out, meta)
    print(table2_markdown(rows))
    print(f"\nwrote {out.with_suffix('.json')} and {out.with_suffix('.md')}")
    return rows


@dataclass(frozen=True)
class ExportSceneConfig:
    """Write one task's scene as viewer-ready MJCF."""

    seed: int = 1_000_000_000
    """Reset seed of the task (the default is the first held-out evaluation task)."""
    env_id: EnvId = ENV_IDS[1]
    """Environment whose task family samples the task."""
    out: Path | None = None
    """MJCF file to write (default: runs/scenes/<env>_seed<SEED>.xml)."""


def export_scene(config: ExportSceneConfig) -> Path:
    """Write a seeded task's scene as MJCF for MuJoCo's viewer (obstacles, target, start key)."""
    import gymnasium as gym

    from clamgen.sim.scene import START_KEY, task_mjcf

    _check_task_seed(config.seed)
    env = gym.make(config.env_id).unwrapped
    env.reset(seed=config.seed)
    task = env.task
    env.close()
    name = config.env_id.split("/")[-1].split("-")[0].lower()
    out = config.out or Path("runs/scenes") / f"{name}_seed{config.seed}.xml"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(task_mjcf(task.start_joints, task.target_position_m, task.obstacles))
    print(f"wrote {out}: {len(task.obstacles)} obstacles, start pose in keyframe {START_KEY!r}")
    print(f"view it: python -m mujoco.viewer --mjcf={out}  (then load key 0, {START_KEY!r})")
    return out


def view(config) -> dict:
    """Watch a policy act live on seeded tasks in MuJoCo's interactive viewer."""
    from clamgen.experiments.checkpoint import CheckpointError
    from clamgen.experiments.viewer import view as run_viewer

    _check_policy(config.policy)
    env_id = _policy_env_id(config.policy)
    if env_id not in ENV_IDS:
        raise SystemExit(
            f"{config.policy} was trained on {env_id}; the viewer shows CLAMGen scenes only "
            "(`clamgen render` films other envs)"
        )
    try:
        policy, _, env_kwargs = _load_policy(config.policy)
        return run_viewer(config, policy, policy_label(config.policy), env_kwargs)
    except (CheckpointError, ValueError) as error:
        raise SystemExit(str(error)) from error


def _view_config(argv: list[str]):
    from clamgen.experiments import viewer

    keys = (viewer.__doc__ or "").split("Keys: ", 1)[-1].split("\n\n")[0]
    return tyro.cli(
        viewer.ViewConfig,
        args=argv,
        prog="clamgen view",
        description=f"{view.__doc__} Keys: {' '.join(keys.split())} {POLICIES_HELP}",
    )


def report(config) -> None:
    """Write results/REPORT.md: Tables 1 and 2 beside the paper, learning curves, speed."""
    from clamgen.experiments.report import build_report

    try:
        page = build_report(config)
    except FileNotFoundError as error:
        raise SystemExit(str(error)) from error
    print(f"wrote {page}")


def _report_config(argv: list[str]):
    from clamgen.experiments.report import ReportConfig

    return tyro.cli(ReportConfig, args=argv, prog="clamgen report")


def sweep(config) -> dict:
    """Run a grid of training runs and their evaluations on Ray; resumable, with a summary."""
    from clamgen.experiments.sweep import SpecError, run_sweep

    try:
        return run_sweep(config)
    except SpecError as error:
        raise SystemExit(str(error)) from error


def _sweep_config(argv: list[str]):
    from clamgen.experiments import sweep as sweep_module

    spec_format = (sweep_module.__doc__ or "").split("The spec (TOML", 1)[-1]
    return tyro.cli(
        sweep_module.SweepConfig,
        args=argv,
        prog="clamgen sweep",
        description=f"{sweep.__doc__} Spec format (TOML{spec_format}",
    )


# Subcommand name -> (config builder from argv, handler). Each handler takes its config.
COMMANDS: dict[str, tuple[Callable, Callable]] = {
    "demo": (lambda argv: tyro.cli(DemoConfig, args=argv, prog="clamgen demo"), demo),
    "train": (_train_config, train),
    "train-residual": (
        lambda argv: _train_config(argv, "residual-cpu", stage=2),
        train_residual,
    ),
    "distill": (lambda argv: _train_config(argv, "residual-cpu", stage=3), distill),
    "eval": (
        lambda argv: tyro.cli(
            EvalConfig,
            args=argv,
            prog="clamgen eval",
            description=f"{evaluate_table.__doc__} {POLICIES_HELP}",
        ),
        evaluate_table,
    ),
    "render": (_render_config, render),
    "report": (_report_config, report),
    "sweep": (_sweep_config, sweep),
    "export-scene": (
        lambda argv: tyro.cli(ExportSceneConfig, args=argv, prog="clamgen export-scene"),
        export_scene,
    ),
    "view": (_view_config, view),
}


def _usage() -> str:
    lines = ["usage: clamgen [--debug] COMMAND [OPTIONS]", "", DESCRIPTION, "", "commands:"]
    for name, (_, handler) in COMMANDS.items():
        lines.append(f"  {name:<14} {(handler.__doc__ or '').splitlines()[0]}")
    lines += [
        "",
        f"presets (train, train-residual --preset NAME): {', '.join(PRESET_NAMES)}",
        f"shipped policies (eval, render, view --policy NAME): {', '.join(SHIPPED_POLICIES)}; "
        f"baselines: {', '.join(BASELINES)}",
        "",
        "Run `clamgen COMMAND --help` for the options of a command. An error is reported in one "
        "line; --debug shows its traceback.",
    ]
    return "\n".join(lines)


# What a bad input, file or environment raises in this project (bad values, bad or missing
# files, an unwritable run directory, a missing optional dependency): reported in one line.
# Other exceptions are bugs and keep their traceback.
USER_ERRORS = (ValueError, OSError, ImportError)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the `clamgen` console command. A user error (`USER_ERRORS`, or a
    command's own message) ends in one line on stderr and exit status 1; `--debug` anywhere on
    the command line shows the traceback instead."""
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv
    argv = [arg for arg in argv if arg != "--debug"]
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(_usage(), file=sys.stderr)
        raise SystemExit(f"\nunknown command {name!r}")
    build_config, handler = COMMANDS[name]
    try:
        with _config_errors_raised():
            config = build_config(rest)
        handler(config)
    except USER_ERRORS as error:
        if debug:
            raise
        raise SystemExit(f"clamgen {name}: {_one_line(str(error))}") from error
    except SystemExit as stop:
        if not isinstance(stop.code, str):  # tyro's usage errors (2), --help (0)
            raise
        if debug and stop.__cause__ is not None:
            traceback.print_exception(stop.__cause__)
        raise SystemExit(f"clamgen {name}: {_one_line(stop.code)}") from stop.__cause__
    except KeyboardInterrupt:
        if debug:
            raise
        print(f"clamgen {name}: interrupted", file=sys.stderr)
        raise SystemExit(130) from None  # the status a shell reports for Ctrl-C


@contextlib.contextmanager
def _config_errors_raised() -> Iterator[None]:
    """Let a config class's own ValueError (from `__post_init__`) propagate out of `tyro.cli`.

    tyro reports a ValueError raised while it builds a nested config in a box and exits 2; here
    it is raised again, so that `main` reports it in one line like any other bad value. tyro's
    hook for that is private (`tyro._errors.on_parse_error`); without it tyro's box stays.
    tyro's own parse errors (unknown flags, values of the wrong type) keep tyro's report."""
    try:
        errors = importlib.import_module("tyro._errors")
        on_parse_error, failure = errors.on_parse_error, errors.InstantiationFailure
    except (ImportError, AttributeError):
        yield
        return

    def raise_config_error(event) -> None:
        # A failure attributed to no single argument comes from a constructor; tyro calls the
        # hook while handling its wrapper, whose context is the constructor's ValueError.
        if isinstance(event, failure) and getattr(event, "argument", None) is None:
            cause = sys.exc_info()[1]
            original = getattr(cause, "__context__", None)
            if isinstance(original, ValueError):
                raise original
            raise ValueError(event.message)

    with on_parse_error(raise_config_error):
        yield


def _one_line(message: str) -> str:
    return "; ".join(line.strip() for line in message.splitlines() if line.strip()) or "error"


if __name__ == "__main__":
    main()
