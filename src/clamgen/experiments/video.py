"""`clamgen render`: MP4 and GIF rollouts of any policy, for people to watch.

Each frame: the outside view (with the tip's path drawn as yellow dots) beside the policy's own
camera views, and a caption with the policy, episode, step and outcome. A step that collided
gets a red border; the episode's last frames say SUCCESS or FAILURE. With `outcome` set, only
episodes that ended that way are filmed: tasks are tried in turn from the first seed, and the
summary says how many were tried.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import imageio.v2 as imageio
import numpy as np
from PIL import Image, ImageDraw
from tqdm import tqdm

from clamgen.envs import ENV_IDS, ENV_TASKS, ReachEnv
from clamgen.experiments.config import check_task_seed
from clamgen.experiments.evaluate import run_episode
from clamgen.experiments.outputs import check_output_stem
from clamgen.experiments.policies import PolicyName
from clamgen.experiments.stall import ESCAPES_BEFORE_PLAN
from clamgen.sim import constants as C
from clamgen.sim.render import MultiViewRenderer

OVERVIEW_SIZE = (480, 640)  # height, width
HOLD_FINAL_FRAMES = 15  # 0.75 s at 20 fps on the outcome
MAX_TRIES = 50
"""Tasks tried at most when only episodes of one outcome are filmed (`RenderConfig.outcome`)."""
GREEN, RED, WHITE = (40, 200, 60), (230, 40, 40), (255, 255, 255)


@dataclass(frozen=True)
class RenderConfig:
    """Render rollouts of a policy to MP4 and GIF."""

    policy: PolicyName | Path = "base"
    """A shipped policy, `ik` (IK interpolation), `rrt`, `depth-rrt-3views` / `-2views` /
    `-1view` (RRT on the depth map of that many views), or a policy file."""
    env_id: str = ENV_IDS[1]
    """A CLAMGen env id (its task family: reach, obstacles, blocked, mixed)."""
    num_episodes: int = 3
    """Episodes, one after the other in the same video."""
    outcome: Literal["any", "success", "failure"] = "any"
    """Film only episodes that ended this way: tasks from --seed on are run in turn until
    --num-episodes of them are found (at most --max-tries tasks); `any` films the first
    --num-episodes tasks."""
    max_tries: int = MAX_TRIES
    """With --outcome success or failure: tasks run at most to find them."""
    seed: int = 1_000_000_000
    """Seed of the first episode (held-out evaluation seeds by default)."""
    target_speed: str = "0"
    """Target speed in m/s, or `variable`."""
    num_views: int = 3
    """Policy camera views shown beside the outside view (0 to 4)."""
    out: Path | None = None
    """Output stem: writes OUT.mp4, OUT.gif and OUT.json (what happened in each episode);
    default runs/videos/<policy> (the policy's name or, for RUN_DIR/policy.pt, the run's)."""
    overwrite: bool = False
    """Replace the output files if they exist (otherwise existing files are kept and nothing
    is rendered)."""
    fps: int = 20
    """Frames per second (the control rate is 20 Hz: real time)."""
    gif_scale: float = 0.5
    """Scale of the GIF frames relative to the MP4's (GIFs get large)."""
    depth_hybrid: bool = False
    """A vision residual acts as Table 2's hybrid rows (shield and planner on 128-pixel depth
    cameras, and from one view the unseen-space test), as `clamgen eval --depth-hybrid`."""
    depth_shield_m: float | None = None
    """A vision residual acts through the collision shield on its own depth images, keeping
    this clearance (m), as `clamgen eval --depth-shield-m`. Off by default."""
    depth_planner: bool = False
    """With --depth-shield-m: plan on the depth map when the policy is stuck, as `clamgen
    eval --depth-planner`."""
    depth_shadow_m: float | None = None
    """With --depth-shield-m: keep the hand out of the arm's shadow near seen obstacle surface,
    as `clamgen eval --depth-shadow-m`."""
    depth_shadow_behind_surfaces: bool = False
    """With --depth-shadow-m: behind any seen surface, as `clamgen eval
    --depth-shadow-behind-surfaces`."""
    depth_bridge_m: float = 0.0
    """With --depth-shield-m: join neighbouring pixels' obstacle points up to this far apart
    by surface, as `clamgen eval --depth-bridge-m`. 0: off."""
    depth_fine_size: int = 0
    """With --depth-shield-m: the shield reads a finer depth camera at this size, as
    `clamgen eval --depth-fine-size`. 0: the policy's own images."""
    depth_plan_checks: int = 0
    """With --depth-planner or --depth-hybrid: a budget of this many validity checks a plan instead
    of 1 s, as `clamgen eval --depth-plan-checks`. 0: the time budget."""
    depth_track_m: float | None = None
    """With --depth-planner or --depth-hybrid (or a `depth-rrt-*` baseline): plan to meet a moving
    target, planning again when it is this far (m) off its course, as `clamgen eval --depth-track-m`
    (0: to where it is)."""
    depth_noise_model_m: float = 0.0
    """With a depth wrapper (or a `depth-rrt-*` baseline): its map told the depth cameras'
    noise model, as `clamgen eval --depth-noise-model-m`. 0: exact depth assumed."""
    depth_goal_zone_m: float = 0.0
    """With --depth-planner or --depth-hybrid: plan to a goal that keeps less than the margin
    keeping 3 mm within this distance of it, as `clamgen eval --depth-goal-zone-m`. 0: off."""
    depth_escapes: bool = False
    """Random escapes from stalls inside the shield, as `clamgen eval --depth-escapes` (alone:
    the escape rows' setting; with --depth-planner, before its plans)."""
    depth_escapes_before_plan: int = ESCAPES_BEFORE_PLAN
    """With --depth-escapes and --depth-planner: the escapes an episode begins before the
    planner may plan, as `clamgen eval --depth-escapes-before-plan`."""
    depth_views: int = 0
    """For a policy that sees no images: this many views rendered for the depth wrapper alone,
    as `clamgen eval --depth-views`. 0: the policy's own views."""
    action_scale: float = 1.0
    """The policy's actions multiplied by this, in (0, 1] (a slower arm), as `clamgen eval
    --action-scale`. 1: as trained."""
    depth_noise_m: float = 0.0
    """Noise on every depth pixel the policy and its wrapper read, standard deviation
    `depth_noise_m * z**2` at depth z (m), as `clamgen eval --depth-noise-m`. 0: exact."""
    real_time: bool = False
    """Acting takes simulated time, as `clamgen eval --table 2 --real-time`: an act longer than
    the 50 ms control period holds the arm still a step for each whole period it took (a
    planner's plans), the target moving on; the captions and the JSON say how many steps it
    held. Depends on the machine's speed (and slows with the rendering beside it)."""


def _caption(frame: np.ndarray, lines: list[tuple[str, tuple[int, int, int]]]) -> np.ndarray:
    image = Image.fromarray(frame)
    draw = ImageDraw.Draw(image)
    y = 8
    for text, color in lines:
        draw.rectangle([6, y - 2, 10 + 7 * len(text), y + 13], fill=(0, 0, 0))
        draw.text((9, y), text, fill=color)
        y += 18
    return np.asarray(image)


def _border(frame: np.ndarray, color, width: int = 6) -> np.ndarray:
    frame = frame.copy()
    frame[:width], frame[-width:], frame[:, :width], frame[:, -width:] = color, color, color, color
    return frame


class RolloutRenderer:
    """Composes video frames of one env: outside view + policy views + caption."""

    def __init__(self, env: ReachEnv, num_views: int) -> None:
        scene = env.scene
        self.scene = scene
        self.overview = MultiViewRenderer(
            scene.model, [scene.overview_camera_id], *OVERVIEW_SIZE, quality="pretty"
        )
        self.num_views = num_views
        side = OVERVIEW_SIZE[0] // max(num_views, 1)
        self.views = (
            MultiViewRenderer(scene.model, scene.camera_ids[:num_views], side, side, "pretty")
            if num_views
            else None
        )

    def frame(self, tip_path: np.ndarray, lines, border=None) -> np.ndarray:
        data = self.scene.data
        outside = self.overview.render(data, markers=tip_path)[0][0]
        outside = _caption(outside, lines)
        if border is not None:
            outside = _border(outside, border)
        if self.views is None:
            return outside
        views = self.views.render(data)[0]
        column = np.concatenate(list(views), axis=0)
        pad = OVERVIEW_SIZE[0] - column.shape[0]
        column = np.pad(column, ((0, pad), (0, 0), (0, 0)))
        return np.concatenate([outside, column], axis=1)

    def close(self) -> None:
        self.overview.close()
        if self.views is not None:
            self.views.close()


def output_stem(config: RenderConfig, label: str) -> Path:
    """Where `config` writes (`config.out`, default runs/videos/`label`); a FileExistsError
    when one of its files exists and `config.overwrite` is False, a ValueError for a stem
    with a stray suffix (`outputs.check_output_stem`)."""
    out = config.out or Path("runs/videos") / label
    return check_output_stem(out, (".mp4", ".gif", ".json"), config.overwrite)


def render_rollouts(config: RenderConfig, policy, label: str, env_kwargs=None) -> dict:
    """Roll out `policy` and write the video files; returns the episode summary."""
    from clamgen.tasks.reach import validate_speed

    if config.env_id not in ENV_IDS:
        raise ValueError(f"env_id must be one of {ENV_IDS}, got {config.env_id!r}")
    if not 0 <= config.num_views <= C.NUM_CAMERAS:
        raise ValueError(f"num_views must be in 0..{C.NUM_CAMERAS}")
    _check_counts(config)
    out = output_stem(config, label)
    speed = validate_speed(
        config.target_speed if config.target_speed == "variable" else float(config.target_speed)
    )
    num_obstacles, family = ENV_TASKS[config.env_id]
    env_kwargs = dict(env_kwargs or {})
    if config.depth_noise_m:  # (the env refuses it without views)
        env_kwargs["depth_noise_m"] = config.depth_noise_m
    env = ReachEnv(
        num_obstacles=num_obstacles, task_family=family, target_speed=speed, **env_kwargs
    )
    renderer = RolloutRenderer(env, config.num_views)

    def episode(seed: int, caption: str) -> tuple[dict, list, list]:
        caption += "  real time" if config.real_time else ""
        film = _EpisodeFilm(renderer, caption)
        record = run_episode(env, policy, seed, on_step=film, real_time=config.real_time)
        outcome = ("SUCCESS" if record.success else "FAILURE", GREEN if record.success else RED)
        steps = f"step {record.steps}"
        steps += f" ({record.held_steps} held while acting)" if config.real_time else ""
        lines = [(f"{caption}  {steps}", WHITE), outcome]
        final = renderer.frame(np.array(film.tips), lines, border=outcome[1])
        frames = film.frames + [final] * HOLD_FINAL_FRAMES
        result = record.outcome() | ({"held_steps": record.held_steps} if config.real_time else {})
        return result, frames, film.gif_frames + [final] * (HOLD_FINAL_FRAMES // 2)

    try:
        summary = _write_films(config, out, label, episode, macro_block_size=8)
    finally:
        renderer.close()
        env.close()
    summary = {"policy": label, "env_id": config.env_id, "target_speed": speed, **summary}
    if config.depth_noise_m:
        summary["depth_noise_m"] = config.depth_noise_m
    if config.real_time:
        from clamgen.experiments.machine import describe

        summary["real_time"] = True
        summary["machine"] = describe()
    out.with_suffix(".json").write_text(json.dumps(summary, indent=2))
    return summary


Episode = Callable[[int, str], tuple[dict, list[np.ndarray], list[np.ndarray]]]
"""`episode(seed, caption)` -> (its outcome as JSON, its video frames, its GIF frames)."""


def _check_counts(config: RenderConfig) -> None:
    if config.num_episodes < 1:
        raise ValueError(f"--num-episodes must be >= 1, got {config.num_episodes}")
    if config.fps < 1:
        raise ValueError(f"--fps must be >= 1, got {config.fps}")
    check_task_seed(config.seed)
    if config.outcome not in ("any", "success", "failure"):
        raise ValueError(f"outcome must be any, success or failure, got {config.outcome!r}")
    if config.outcome != "any" and config.max_tries < config.num_episodes:
        raise ValueError(
            f"--max-tries ({config.max_tries}) must be >= --num-episodes ({config.num_episodes})"
        )


def _seeds(config: RenderConfig) -> Iterator[int]:
    """The seeds of the tasks to run, in turn: the first `num_episodes` ones, or with an
    `outcome` to film, up to `max_tries` of them."""
    tries = config.num_episodes if config.outcome == "any" else config.max_tries
    return iter(range(config.seed, config.seed + tries))


def _write_films(config: RenderConfig, out: Path, label: str, episode: Episode, **writer) -> dict:
    """Runs `episode` on the tasks of `_seeds` and writes OUT.mp4 and OUT.gif of those with the
    wanted outcome (every one with `outcome` "any") until `num_episodes` are kept; returns the
    summary's episodes, tasks tried, outcome asked and file names. A one-line ValueError, and
    no files, when no task ended that way."""
    mp4_path, gif_path = out.with_suffix(".mp4"), out.with_suffix(".gif")
    kept: list[dict] = []
    gif_frames: list[np.ndarray] = []
    video = None
    tried = 0
    filtering = config.outcome != "any"
    total = config.max_tries if filtering else config.num_episodes
    bar = tqdm(total=total, unit="task" if filtering else "episode", desc="rendering")
    try:
        for seed in _seeds(config):
            caption = f"{label}  episode {len(kept) + 1}/{config.num_episodes}"
            result, frames, gif = episode(seed, f"{caption}  seed {seed}" if filtering else caption)
            tried += 1
            bar.update(1)
            if filtering and result["success"] != (config.outcome == "success"):
                continue
            if video is None:
                out.parent.mkdir(parents=True, exist_ok=True)
                video = imageio.get_writer(mp4_path, fps=config.fps, **writer)
            for frame in frames:
                video.append_data(frame)
            gif_frames += gif
            kept.append(result)
            bar.set_postfix(kept=len(kept), success=f"{np.mean([e['success'] for e in kept]):.2f}")
            if len(kept) == config.num_episodes:
                break
    finally:
        bar.close()
        if video is not None:
            video.close()
    if not kept:
        raise ValueError(
            f"none of the {tried} tasks from seed {config.seed} ended in {config.outcome}; "
            "raise --max-tries or pick another --seed"
        )
    _save_gif(gif_path, gif_frames, config)
    return {
        "outcome": config.outcome,
        "tasks_tried": tried,
        "episodes": kept,
        "mp4": str(mp4_path),
        "gif": str(gif_path),
    }


class _EpisodeFilm:
    """The frames of one episode, fed by the rollout loop's step hook: one per step with the tip
    path so far, plus a red-bordered one for each step that collided; every other frame also
    goes to the GIF's frames."""

    def __init__(self, renderer, caption: str) -> None:
        self.renderer, self.caption = renderer, caption
        self.frames: list[np.ndarray] = []
        self.gif_frames: list[np.ndarray] = []
        self.tips: list[np.ndarray] = []
        self.collided = False

    def lines(self, steps: int) -> list[tuple[str, tuple[int, int, int]]]:
        status = ("COLLISION", RED) if self.collided else ("running", WHITE)
        return [(f"{self.caption}  step {steps}", WHITE), status]

    def __call__(self, obs: dict, info: dict | None, done: bool) -> None:
        self.tips.append(obs["achieved_goal"].copy())
        steps = len(self.tips) - 1
        if info is not None and info["collision"]:
            # The step that collided, with the status it started from, in a red border.
            lines = self.lines(steps - 1)
            self.frames.append(self.renderer.frame(np.array(self.tips), lines, border=RED))
            self.collided = True
        if not done:
            frame = self.renderer.frame(np.array(self.tips), self.lines(steps))
            self.frames.append(frame)
            if steps % 2 == 0:
                self.gif_frames.append(frame)


def _save_gif(path: Path, frames: list[np.ndarray], config: RenderConfig) -> None:
    """The GIF of every other frame: scaled by `gif_scale`, at half the video's frame rate."""
    scaled = [_scale(f, config.gif_scale) for f in frames]
    imageio.mimsave(path, scaled, duration=2 / config.fps, loop=0)


def _scale(frame: np.ndarray, scale: float) -> np.ndarray:
    if scale == 1.0:
        return frame
    height, width = frame.shape[:2]
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    return np.asarray(Image.fromarray(frame).resize(size, Image.BILINEAR))


def render_env_rollouts(config: RenderConfig, policy, label: str, env_id: str) -> dict:
    """Roll out `policy` in another goal-conditioned env (`make_goal_env`: a Gymnasium id or
    `module:id`) and write OUT.mp4, OUT.gif and OUT.json from the env's own `rgb_array` frames,
    captioned like the CLAMGen videos. `config.env_id`, `num_views` and `target_speed` are
    CLAMGen settings and do not apply. A one-line ValueError when the env cannot be made, does
    not render frames, or does not fit the policy."""
    from clamgen.experiments.evaluate import check_policy_fits, make_goal_env

    _check_counts(config)
    if config.real_time:
        raise ValueError("--real-time needs a CLAMGen env (its control period)")
    out = output_stem(config, label)
    env = make_goal_env(env_id, render_mode="rgb_array")

    def episode(seed: int, caption: str) -> tuple[dict, list, list]:
        frames: list[np.ndarray] = []

        def film(obs, info, done) -> None:
            lines = [(f"{caption}  step {len(frames)}", WHITE)]
            frames.append(_caption(np.asarray(env.render()), lines))

        record = run_episode(env, policy, seed, on_step=film)
        outcome = ("SUCCESS" if record.success else "FAILURE", GREEN if record.success else RED)
        final = _caption(frames[-1], [(f"{caption}  step {record.steps}", WHITE), outcome])
        frames += [_border(final, outcome[1], width=2)] * HOLD_FINAL_FRAMES
        result = {"seed": seed, "success": record.success, "steps": record.steps}
        if record.collisions_reported:
            result["collided"] = record.collided
        return result, frames, frames[::2]

    try:
        check_policy_fits(policy, env, env_id)
        summary = _write_films(config, out, label, episode, macro_block_size=1)
    finally:
        env.close()
    summary = {"policy": label, "env_id": env_id, **summary}
    out.with_suffix(".json").write_text(json.dumps(summary, indent=2))
    return summary
