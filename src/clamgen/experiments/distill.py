"""Distil a privileged residual into a vision residual with DAgger (beyond the paper).

The privileged residual sees the obstacles' true poses and trains in minutes; the vision
residual has to find the same behaviour from camera views, by RL, at many times the cost. Here
the vision student instead imitates the privileged teacher (Ross et al. 2011's DAgger, as in
teacher-student training for legged robots and "learning by cheating" for driving):

1. iteration 0: the teacher drives `episodes_per_iteration` training episodes; every visited
   state is stored with the student's inputs (views, joints, goal) and the teacher's label;
2. later iterations: the student drives, the teacher only labels (the teacher drives a share
   `teacher_share ** iteration` of the episodes), so that the data covers the states the
   student's own mistakes lead to;
3. after each iteration the student (encoder and actor, on the frozen base as CLAMGen's
   residual) regresses the teacher's pre-squash mean action on all data so far, with CURL's
   random crops and view dropout, and is scored on validation tasks.

With `lookahead_candidates` > 0 the teacher plans before each label: it rolls itself out in a
copy of the simulator and bends its action by the best of perturbed plans
(`clamgen.experiments.lookahead`), so that the labels avoid the collisions and stalls the
teacher's own action would run into; it still acts and labels in one step per state.

The label is the teacher's combined action before the tanh (`ResidualAgent.mean_action`),
clipped to +-`TARGET_CLIP`, so that a saturated action is still learned as saturated without
chasing an unbounded target. The student's policy file is a residual policy like
`clamgen train-residual`'s: `clamgen eval` and `clamgen render` take it.

The student may also be a privileged residual (`agent.obs_source obstacles`: true obstacle
poses, nothing rendered), which trains in about half a vision student's time. Its encoder and
batch are not the vision student's, so it is no upper bound for one: with the same loop it
scores below the vision students (results/stage2/distill/README.md).

Resumable at iteration granularity: each iteration's data and the student after it are written
to the run directory; running the same command again continues after the last finished one.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NamedTuple, get_args

import numpy as np
import torch
from tqdm import tqdm

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments import lookahead
from clamgen.experiments.config import (
    TRAINING_SEEDS,
    VALIDATION_SEEDS,
    _require_int,
    config_to_json,
)
from clamgen.experiments.evaluate import SACPolicy, evaluate, summarize
from clamgen.experiments.lookahead import LookaheadPolicy, LookaheadTeacher
from clamgen.experiments.stage2 import Stage2Config, load_residual_agent, residual_stage
from clamgen.experiments.train import POLICY_NAME, MetricLogger, make_env

# Teacher labels: pre-squash means clipped to this (tanh(3) = 0.995, a saturated step); the
# lookahead teacher's labels and rollouts use the same bound.
TARGET_CLIP = lookahead.PRE_SQUASH_CLIP
# What `DistillSettings.action_loss_kind` may be.
ActionLossKind = Literal["squared", "absolute"]
ACTION_LOSS_KINDS = get_args(ActionLossKind)
# Env reset seeds of distillation episodes: training seeds far from the RL runs' (loop seed *
# 1000 + env index) and from results/stage2/tune/distill.py's.
DISTILL_SEED_BASE = 800_000_000
# Observation keys a vision student reads (the teacher also reads `obstacles`); a privileged
# student (`student_keys`) reads `obstacles` in place of `images`.
STUDENT_KEYS = ("images", "observation", "achieved_goal", "desired_goal")
STATE_NAME = "student.pt"
DRIVER_NOISE_STREAM = 2
"""The second number of the seed of `driver_noise`'s random stream (the episodes' is 1)."""
# Numbers per obstacle in the `obstacles` observation (`Obstacles.as_array`): the kind's one-hot
# (2), then lengths in metres: the centre (3) and the half sizes (3).
POSE_SIZE = 8
POSE_LENGTHS = slice(2, 8)


@dataclass(frozen=True)
class DistillSettings:
    """The DAgger loop: data per iteration, regression, validation."""

    teacher: str = ""
    """Policy file of a privileged residual (`--agent.obs-source obstacles`), the teacher."""
    iterations: int = 6
    """DAgger iterations (iteration 0 is driven by the teacher)."""
    episodes_per_iteration: int = 300
    """Training episodes collected per iteration."""
    updates_per_iteration: int = 4000
    """Regression steps on all data so far after each iteration."""
    teacher_share: float = 0.5
    """Iteration k >= 1: the teacher drives a share teacher_share ** k of the episodes."""
    lr: float = 3e-4
    """Adam learning rate of the student's encoder and actor."""
    weight_decay: float = 0.0
    """Decoupled weight decay of the regression, as AdamW's (beyond the paper): every step
    also shrinks each weight by the learning rate times this. 0: plain Adam, as every run
    before it was added."""
    final_updates: int = 0
    """After the last iteration, this many more regression steps on all data with the learning
    rate decayed from `lr` to 0 along a cosine ("polishing"); the polished student is validated
    like an iteration, saved as `policy_final.pt`, and becomes `policy.pt` if it is the best.
    A finished run is polished by running it again with this set. 0: none."""
    pose_weight: float = 1.0
    """Vision students: weight of an auxiliary loss that regresses the obstacles' true poses
    from the student's visual encoding (a training-only linear head; the loss takes the best
    matching of the predicted to the true obstacles, whose order is arbitrary). 0: off."""
    pose_length_scale_m: float = 1.0
    """Lengths in the pose loss are measured in this unit (m). In metres (1.0, every run
    before it was added) an error of 8 cm costs 0.0064, a hundredth of the action loss, so the
    loss shapes the encoder hardly at all (`pose_error.py`: the head's centre error is 8-9 cm
    against 11-13 cm for a constant guess); 0.05 makes a 5 cm error cost 1."""
    num_eval_episodes: int = 100
    """Validation tasks (`VALIDATION_SEEDS`) scored after each iteration; the best iteration's
    student becomes `policy.pt`."""
    lookahead_candidates: int = 0
    """> 0: the teacher plans before each label with rollouts of itself in the simulator, this
    many perturbed plans when its current plan does not arrive cleanly
    (`clamgen.experiments.lookahead`); 0: the teacher's own action."""
    lookahead_horizon: int = lookahead.HORIZON
    """Steps per lookahead rollout."""
    lookahead_noise: float = lookahead.NOISE
    """Standard deviation of the lookahead's plan offsets (pre-squash units)."""
    lookahead_segments: int = lookahead.SEGMENTS
    """Pieces of constant offset along a lookahead plan."""
    lookahead_margin_m: float = lookahead.MARGIN_M
    """Clearance (m) the lookahead's plans keep from obstacles and the table where they can,
    so that the student's labels leave room for its own errors (0: true contact)."""
    stop_at_collision: bool = False
    """Collection episodes end at their first collision. An episode that collided has failed
    (success means no collision at any step), but the arm stops before contact and the episode
    runs on: a student pressed against an obstacle until the time limit adds most of an
    iteration's states, all after its failure. False: episodes run to the time limit, as
    every run before it was added."""
    lookahead_prefer_student: bool = False
    """In the student's episodes, the lookahead's searches keep the clean plan nearest to the
    student's own action instead of the earliest arrival, so that labels keep the side of an
    obstacle the student takes (`clamgen.experiments.lookahead`). False: the earliest, as
    every run before it was added."""
    lookahead_fixed_offsets: bool = False
    """The lookahead searches among one fixed library of perturbed plans (drawn once from the
    seed) instead of fresh draws at every search, so that nearby states get consistent labels
    (`clamgen.experiments.lookahead`). False: fresh draws, as every run before it was added."""
    lookahead_least_offset: bool = False
    """The lookahead's searches keep the clean plan whose offsets are smallest (the least
    deviation from the teacher's own actions) instead of the earliest arrival
    (`clamgen.experiments.lookahead`). Not with `lookahead_prefer_student`."""
    near_target_weight: float = 1.0
    """Regression batches draw the states whose target lies within `near_target_m` of an
    obstacle's surface this many times as often as the others (beyond the paper; 1: uniform,
    as every run before it was added). The blocked tasks that every 3-view student fails have
    their target next to an obstacle (`results/stage2/ensemble/shared_failures.py`)."""
    near_target_m: float = 0.02
    """The distance (m) from the target to the nearest obstacle's axis-aligned box under which
    a state counts as near for `near_target_weight`."""
    near_tip_weight: float = 1.0
    """Regression batches draw the states whose tip lies within `near_tip_m` of the target this
    many times as often as the others (beyond the paper; 1: uniform, as every run before it was
    added; with `near_target_weight` too, the two weights multiply). The 3-view students' stalls
    on goals with room to spare end a few centimetres from the target, where even on their own
    data they fit the labels less well (`results/stage2/ensemble/hover_labels.py`)."""
    near_tip_m: float = 0.05
    """The tip-to-target distance (m) under which a state counts as near for `near_tip_weight`
    (success is within 0.02, where an episode ends)."""
    pre_squash_loss_weight: float = 1.0
    """Weight of the imitation loss's mean squared error before the tanh, between the
    student's pre-squash mean and the label (every run before `action_loss_weight` was added:
    1, alone)."""
    action_loss_weight: float = 0.0
    """Weight of the mean squared error after the tanh, between the actions the student and
    the label take (beyond the paper; 0: off). Labels are clipped at +-TARGET_CLIP before the
    tanh and a quarter of their components lie beyond 2 (tanh 0.96, a nearly full step), where
    a pre-squash error of 1 moves the action by under 0.1 but costs as much as anywhere: the
    pre-squash loss spends about half its weight there. After the tanh, errors weigh what they
    move the arm; a small `pre_squash_loss_weight` beside it keeps a gradient on a saturated
    mean of the wrong sign. (Measured in session 52 with weights 1 and 0.05: no gain for the
    3-view students, `results/stage2/distill/README.md`, "The loss after the tanh".)"""
    action_loss_kind: ActionLossKind = "squared"
    """The error after the tanh that `action_loss_weight` weighs: "squared" (its mean square:
    where labels at nearby states disagree, their mean) or "absolute" (its mean absolute
    value: per component, their median, which keeps the side most labels take where they
    pass an obstacle both ways)."""
    driver_noise: float = 0.0
    """Standard deviation of Gaussian noise added to each joint of the student's action where
    the student drives an episode (the action then clipped to [-1, 1]); the teacher labels the
    states the noisy actions reach, and its own driving and validation stay noise-free (beyond
    the paper; 0: off, every run before it was added). DART's remedy (Laskey et al., 2017)
    for a student that fails where it leaves its own path: its data then also holds the
    states around that path."""
    seed: int = 0
    """Seed of the episodes (training seeds from `DISTILL_SEED_BASE + seed * 100000`), the
    student's initialisation and its batches."""

    def __post_init__(self) -> None:
        for name in ("iterations", "episodes_per_iteration", "num_eval_episodes"):
            _require_int(f"distill.{name}", getattr(self, name), 1)
        _require_int("distill.updates_per_iteration", self.updates_per_iteration, 0)
        _require_int("distill.final_updates", self.final_updates, 0)
        _require_int("distill.seed", self.seed, 0, 999)
        _require_int("distill.lookahead_candidates", self.lookahead_candidates, 0)
        _require_int("distill.lookahead_horizon", self.lookahead_horizon, 1)
        _require_int("distill.lookahead_segments", self.lookahead_segments, 1)
        if not 0 <= self.lookahead_noise < float("inf"):
            raise ValueError(
                f"distill.lookahead_noise must be a number >= 0, got {self.lookahead_noise}"
            )
        if not 0 <= self.driver_noise < float("inf"):
            raise ValueError(f"distill.driver_noise must be a number >= 0, got {self.driver_noise}")
        if not 0 <= self.lookahead_margin_m < float("inf"):
            raise ValueError(
                f"distill.lookahead_margin_m must be a number >= 0, got {self.lookahead_margin_m}"
            )
        if self.lookahead_least_offset and self.lookahead_prefer_student:
            raise ValueError(
                "distill.lookahead_least_offset and distill.lookahead_prefer_student are two "
                "ways to choose among clean plans: one"
            )
        if not 0 <= self.teacher_share <= 1:
            raise ValueError(f"distill.teacher_share must be in [0, 1], got {self.teacher_share}")
        if not 0 < self.pose_length_scale_m < float("inf"):
            raise ValueError(
                f"distill.pose_length_scale_m must be a number > 0, got {self.pose_length_scale_m}"
            )
        if not 0 <= self.pose_weight < float("inf"):
            raise ValueError(f"distill.pose_weight must be a number >= 0, got {self.pose_weight}")
        if not self.lr > 0:
            raise ValueError(f"distill.lr must be > 0, got {self.lr}")
        if not 0 <= self.weight_decay < float("inf"):
            raise ValueError(f"distill.weight_decay must be a number >= 0, got {self.weight_decay}")
        for name in ("pre_squash_loss_weight", "action_loss_weight"):
            if not 0 <= getattr(self, name) < float("inf"):
                raise ValueError(f"distill.{name} must be a number >= 0, got {getattr(self, name)}")
        if self.action_loss_kind not in ACTION_LOSS_KINDS:
            raise ValueError(
                f"distill.action_loss_kind must be one of {ACTION_LOSS_KINDS}, "
                f"got {self.action_loss_kind!r}"
            )
        if self.pre_squash_loss_weight == 0 and self.action_loss_weight == 0:
            raise ValueError(
                "distill.pre_squash_loss_weight and distill.action_loss_weight are both 0: "
                "the student would learn nothing"
            )
        if not 0 < self.near_target_weight < float("inf"):
            raise ValueError(
                f"distill.near_target_weight must be a number > 0, got {self.near_target_weight}"
            )
        if not 0 < self.near_tip_weight < float("inf"):
            raise ValueError(
                f"distill.near_tip_weight must be a number > 0, got {self.near_tip_weight}"
            )
        if not 0 <= self.near_tip_m < float("inf"):
            raise ValueError(f"distill.near_tip_m must be a number >= 0, got {self.near_tip_m}")
        if not 0 <= self.near_target_m < float("inf"):
            raise ValueError(
                f"distill.near_target_m must be a number >= 0, got {self.near_target_m}"
            )


@dataclass(frozen=True)
class DistillConfig:
    """Everything `clamgen distill` needs: the student (a stage-2 config, from a preset) and
    the DAgger settings."""

    student: Stage2Config = field(default_factory=Stage2Config)
    """The student (a vision residual, or a privileged one): env (views, image size, task
    family), agent, base policy, run_dir."""
    distill: DistillSettings = field(default_factory=DistillSettings)
    """The DAgger loop."""


def target_clearance_m(goals: np.ndarray, obstacles: np.ndarray) -> np.ndarray:
    """(N,) distance (m) from each state's target (N, 3) to the nearest of its obstacles
    (N, K, POSE_SIZE as `Obstacles.as_array`), each taken as its axis-aligned box; 0 inside."""
    centres, halves = obstacles[..., 2:5], obstacles[..., 5:8]
    outside = np.maximum(np.abs(goals[:, None, :] - centres) - halves, 0.0)
    return np.linalg.norm(outside, axis=-1).min(axis=-1)


def student_keys(obs_source: str, previous_action: bool = False) -> tuple[str, ...]:
    """Observation keys a student of this `agent.obs_source` (and `agent.previous_action`)
    reads."""
    keys = STUDENT_KEYS if obs_source == "images" else ("obstacles", *STUDENT_KEYS[1:])
    return (*keys, "previous_action") if previous_action else keys


class RegressionLoss(NamedTuple):
    """What `Distiller.regress` returns: the imitation loss (with any added heads' losses) of
    its last batch, and its mean over its `batches` batches (a steadier reading of the fit)."""

    last: float | None
    mean: float | None
    batches: int = 0


class _Dataset:
    """The aggregated (student input, teacher label) pairs, in growing numpy arrays."""

    def __init__(self, keys: tuple[str, ...] = STUDENT_KEYS) -> None:
        self.arrays: dict[str, np.ndarray] = {}
        self.keys = keys

    def add(self, chunk: dict[str, np.ndarray]) -> None:
        if not self.arrays:
            self.arrays = dict(chunk)
            return
        self.arrays = {k: np.concatenate([self.arrays[k], chunk[k]]) for k in chunk}

    def __len__(self) -> int:
        return len(self.arrays.get("label", ()))

    def column(self, key: str) -> np.ndarray:
        """Every state's `key`, in index order."""
        return self.arrays[key]

    def batch(self, index: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
        obs = {k: self.arrays[k][index] for k in self.keys}
        return obs, self.arrays["label"][index]

    def poses(self, index: np.ndarray) -> np.ndarray:
        """The true obstacle poses of the states `index` (the pose loss's targets)."""
        return self.arrays["obstacles"][index]


class Distiller:
    """DAgger from a privileged teacher into a student; see the module docstring.

    `run()` is the whole loop. Its steps are public for loops of one's own (continuing DAgger
    from a student regressed elsewhere: `results/stage2/distill/continue_dagger.py`):
    `collect_iteration` (episodes, every state labelled), `regress` (steps on `data`, whose
    batches `batch_index` draws: override it to weight them), `validate` and `policy_payload`
    (a policy file's contents); `resume_state` / `load_resume_state` save and restore the rest.
    """

    def __init__(self, config: DistillConfig) -> None:
        self.config = config
        settings = config.distill
        if not settings.teacher:
            raise ValueError("distill.teacher is required: a privileged residual policy file")
        self.teacher, teacher_config = load_residual_agent(
            ckpt.resolve_policy_path(settings.teacher)
        )
        if teacher_config.agent.obs_source != "obstacles":
            raise ValueError(
                f"distill.teacher {settings.teacher} is not a privileged residual "
                "(agent.obs_source 'obstacles')"
            )
        student = config.student
        # A student may read true obstacle poses instead of images (nothing rendered); the
        # pose loss is for vision students.
        self.vision = student.agent.obs_source == "images"
        self.keys = student_keys(student.agent.obs_source, student.agent.previous_action)
        torch.set_num_threads(student.loop.torch_threads)
        self.run_dir = Path(student.run_dir)
        # Collection envs show the teacher the poses too; the student's own env does not.
        collect = dataclasses.replace(student.env, include_obstacle_state=True)
        self.envs = [make_env(collect, training=True) for _ in range(student.env.num_envs)]
        self.eval_env = make_env(student.env)
        self.stage = residual_stage(
            dataclasses.replace(student, loop=dataclasses.replace(student.loop, seed=settings.seed))
        )
        self.student = self.stage.make_agent(self.envs[0])
        num_obstacles = self.envs[0].unwrapped.num_obstacles
        self.lookahead = (
            LookaheadTeacher(
                self.teacher,
                num_obstacles,
                candidates=settings.lookahead_candidates,
                horizon=settings.lookahead_horizon,
                noise=settings.lookahead_noise,
                segments=settings.lookahead_segments,
                seed=settings.seed,
                margin_m=settings.lookahead_margin_m,
                fixed_offsets=settings.lookahead_fixed_offsets,
                least_offset=settings.lookahead_least_offset,
            )
            if settings.lookahead_candidates
            else None
        )
        # One plan-following labeller per collection env (reset with its episodes).
        self.planners = (
            [LookaheadPolicy(self.lookahead) for _ in self.envs] if self.lookahead else []
        )
        with torch.random.fork_rng(devices=[]):  # its initial weights from the distill seed
            torch.manual_seed(settings.seed)
            self.pose_head = torch.nn.Linear(self.student.feature_dim, num_obstacles * POSE_SIZE)
        params = [
            *self.student.critic.encoder.parameters(),
            *self.student.actor.parameters(),
            *(self.pose_head.parameters() if self._pose_loss_on() else ()),
        ]
        self.optimizer = torch.optim.Adam(
            params, lr=settings.lr, weight_decay=settings.weight_decay, decoupled_weight_decay=True
        )
        self.heads: dict[str, torch.nn.Module] = {}  # `add_head`'s, by name
        self.rng = np.random.default_rng([settings.seed, 1])
        # Its own stream, so that the noise leaves the episodes' and batches' draws as they were.
        self.noise_rng = np.random.default_rng([settings.seed, DRIVER_NOISE_STREAM])
        self.data = _Dataset(self.keys)
        self._weights_cdf = np.zeros(0)  # the near weights', for the data's current size
        self.history: list[dict[str, Any]] = []
        self.final: dict[str, Any] | None = None  # the polished student's validation
        self.next_seed = DISTILL_SEED_BASE + settings.seed * 100_000

    # ------------------------------------------------------------------ the loop
    def run(self, show_progress: bool = True) -> dict[str, Any]:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        start = self._resume()
        (self.run_dir / "config.json").write_text(_config_json(self.config))
        # metrics.csv and TensorBoard, against labelled states (the env steps collected so far).
        metrics = MetricLogger(self.run_dir, self.history[-1]["samples"] if self.history else None)
        try:
            self._iterate(start, metrics, show_progress)
        finally:
            metrics.close()
        if self.config.distill.final_updates and self.final is None:
            self._polish(show_progress)
        best = max(self._scored(), key=lambda r: r["validation/success_rate"])
        summary = {
            "best_iteration": best["iteration"],
            **best,
            "iterations": self.history,
            **({"final": self.final} if self.final else {}),
        }
        (self.run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        return summary

    def _iterate(self, start: int, metrics: MetricLogger, show_progress: bool) -> None:
        settings = self.config.distill
        for iteration in range(start, settings.iterations):
            tic = time.perf_counter()
            share = 1.0 if iteration == 0 else settings.teacher_share**iteration
            chunk, stats = self.collect_iteration(share, iteration, show_progress)
            ckpt.save_npz(self.run_dir / "data" / f"iteration{iteration}.npz", chunk)
            self.data.add(chunk)
            loss, loss_mean, _ = self.regress(
                settings.updates_per_iteration, iteration, show_progress
            )
            scores = self.validate()
            row = {
                "iteration": iteration,
                "teacher_share": share,
                "samples": len(self.data),
                **stats,
                "loss": loss,
                "loss_mean": loss_mean,
                **{f"validation/{k}": v for k, v in scores.items()},
                "seconds": time.perf_counter() - tic,
            }
            self.history.append(row)
            print(json.dumps(row), flush=True)
            logged = {
                "eval/success_rate": scores["success_rate"],
                "eval/collision_rate": scores["collision_rate"],
                "distill/loss": loss,
                "distill/loss_mean": loss_mean,
                "distill/rollout_success": stats["rollout_success"],
                "distill/teacher_success": stats["teacher_success"],
            }
            wall_time = sum(r["seconds"] for r in self.history)
            # Logged before the checkpoint: a kill between the two drops the row on resume.
            metrics.log(
                len(self.data), wall_time, {k: v for k, v in logged.items() if v is not None}
            )
            self._save(iteration, scores["success_rate"])

    def _polish(self, show_progress: bool) -> None:
        """`final_updates` regression steps with a cosine-decayed learning rate, then validate
        and save the polished student."""
        tic = time.perf_counter()
        steps = self.config.distill.final_updates
        loss, loss_mean, _ = self.regress(steps, "final", show_progress, decay_over=(0, steps))
        scores = self.validate()
        self.final = {
            "iteration": "final",
            "samples": len(self.data),
            "updates": steps,
            "loss": loss,
            "loss_mean": loss_mean,
            **{f"validation/{k}": v for k, v in scores.items()},
            "seconds": time.perf_counter() - tic,
        }
        print(json.dumps(self.final), flush=True)
        self._save("final", scores["success_rate"])

    def _scored(self) -> list[dict[str, Any]]:
        """Every validated student: the iterations', then the polished one's."""
        return [*self.history, *([self.final] if self.final else [])]

    def collect_iteration(self, share: float, iteration: int, show_progress: bool):
        """`episodes_per_iteration` episodes, the teacher driving each with probability
        `share`; every state labelled by the teacher (with lookahead, when configured).
        (chunk of arrays, stats): the stats are the success rates (reached, never collided) of
        the student-driven (`rollout_success`) and teacher-driven episodes (None: none such),
        and the lookahead's rollouts and searches."""
        wanted = self.config.distill.episodes_per_iteration
        saved = tuple(dict.fromkeys((*self.keys, "obstacles")))
        rows: dict[str, list[np.ndarray]] = {k: [] for k in (*saved, "label")}
        driver = [False] * len(self.envs)
        obs = [self._reset(i, share, driver) for i in range(len(self.envs))]
        started, finished = len(self.envs), 0
        outcomes: dict[bool, list[bool]] = {True: [], False: []}  # by driver: teacher?
        bar = tqdm(total=wanted, desc=f"iteration {iteration} episodes", disable=not show_progress)
        active = list(range(len(self.envs)))
        collided = [False] * len(self.envs)
        noise = self.config.distill.driver_noise
        if self.lookahead is not None:
            counts = (self.lookahead.rollouts, self.lookahead.searches)
        while active:
            batch = {k: np.stack([obs[i][k] for i in active]) for k in obs[active[0]]}
            if all(driver[i] for i in active):
                student = None  # the teacher drives every episode
            else:
                student = self.student.act(batch, deterministic=True)
            if self.lookahead is None:
                labels = np.clip(self.teacher.mean_action(batch), -TARGET_CLIP, TARGET_CLIP)
            else:
                labels = np.stack(
                    [
                        self.planners[i].label(obs[i], self._preferred(student, j, driver[i]))
                        for j, i in enumerate(active)
                    ]
                )
            for key in saved:
                rows[key].append(batch[key])
            rows["label"].append(labels.astype(np.float32))
            still = []
            for j, i in enumerate(active):
                action = np.tanh(labels[j]) if driver[i] else student[j]
                if noise and not driver[i]:
                    jolt = self.noise_rng.normal(0.0, noise, action.shape)
                    action = np.clip(action + jolt, -1.0, 1.0)
                if not driver[i] and self.planners:
                    self.planners[i].off_plan()
                obs[i], _, terminated, truncated, info = self.envs[i].step(action)
                collided[i] |= bool(info["collision"])
                stop = collided[i] and self.config.distill.stop_at_collision
                if not (terminated or truncated or stop):
                    still.append(i)
                    continue
                finished += 1
                bar.update()
                outcomes[driver[i]].append(bool(info["is_success"]) and not collided[i])
                if started < wanted:
                    obs[i] = self._reset(i, share, driver)
                    collided[i] = False
                    started += 1
                    still.append(i)
            active = still
        bar.close()
        chunk = {k: np.concatenate(v) for k, v in rows.items()}
        stats = {
            "rollout_success": float(np.mean(outcomes[False])) if outcomes[False] else None,
            "teacher_success": float(np.mean(outcomes[True])) if outcomes[True] else None,
        }
        if self.lookahead is not None:
            stats["lookahead_rollouts"] = self.lookahead.rollouts - counts[0]
            stats["lookahead_searches"] = self.lookahead.searches - counts[1]
        return chunk, stats

    def _preferred(self, student: np.ndarray | None, j: int, teacher_drives: bool):
        """The student's pre-squash action for the lookahead to prefer (None: no preference)."""
        if student is None or teacher_drives or not self.config.distill.lookahead_prefer_student:
            return None
        return np.arctanh(np.clip(student[j], -np.tanh(TARGET_CLIP), np.tanh(TARGET_CLIP)))

    def _reset(self, i: int, share: float, driver: list[bool]) -> dict[str, np.ndarray]:
        seed = self.next_seed
        if seed not in TRAINING_SEEDS:  # pragma: no cover - needs 10^8 episodes
            raise ValueError(f"distillation ran out of training seeds at {seed}")
        self.next_seed += 1
        driver[i] = bool(self.rng.random() < share)
        obs = self.envs[i].reset(seed=seed)[0]
        if self.planners:
            self.planners[i].reset(self.envs[i])
        return obs

    def regress(
        self,
        steps: int,
        iteration: int | str,
        show_progress: bool,
        decay_over: tuple[int, int] | None = None,
    ) -> RegressionLoss:
        """`steps` Adam steps of the imitation loss on random batches of all data. With
        `decay_over=(first, total)` the learning rate falls from `lr` to 0 along a cosine over
        `total` steps, of which these are steps `first`, `first + 1`, ... (`(0, steps)`: over
        these alone; a long regression run in chunks follows one cosine). Returns the last
        batch's loss and the mean over the `steps` batches (None for 0 steps)."""
        batch_size = self.config.student.agent.batch_size
        lr = self.config.distill.lr
        if decay_over is not None and not 0 <= decay_over[0] <= decay_over[1] - steps:
            raise ValueError(f"decay_over {decay_over}: {steps} steps do not fit in it")
        losses = []
        for step in tqdm(
            range(steps), desc=f"iteration {iteration} regression", disable=not show_progress
        ):
            if decay_over is not None:
                first, total = decay_over
                for group in self.optimizer.param_groups:
                    group["lr"] = 0.5 * lr * (1 + np.cos(np.pi * (first + step) / total))
            index = self.batch_index(batch_size)
            obs, labels = self.data.batch(index)
            loss, visual = self.student.imitation_loss(
                obs,
                torch.as_tensor(labels),
                pre_squash_weight=self.config.distill.pre_squash_loss_weight,
                action_weight=self.config.distill.action_loss_weight,
                action_absolute=self.config.distill.action_loss_kind == "absolute",
            )
            if self._pose_loss_on():
                poses = torch.as_tensor(self.data.poses(index))
                loss = loss + self.config.distill.pose_weight * pose_loss(
                    self.pose_head(visual).view(poses.shape),
                    scale_lengths(poses, self.config.distill.pose_length_scale_m),
                )
            extra = self.extra_loss(index, obs, visual)
            if extra is not None:
                loss = loss + extra
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            losses.append(float(loss.detach()))
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        if not losses:
            return RegressionLoss(None, None)
        return RegressionLoss(losses[-1], float(np.mean(losses)), len(losses))

    def add_head(self, name: str, build) -> torch.nn.Module:
        """Another head regressed beside the student (for `extra_loss`): `build()` makes it with
        its initial weights from the distill seed, its parameters join the optimizer, and its
        weights are kept in the regression state under `name`. Returns it."""
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.config.distill.seed)
            head = build()
        self.optimizer.add_param_group({"params": list(head.parameters())})
        self.heads[name] = head
        return head

    def actor_features_dim(self) -> int:
        """Width of the student's actor features (what heads on them read)."""
        probe = self.student.actor.features(
            torch.zeros(1, self.student.feature_dim),
            torch.zeros(1, self.student.config.encoder.low_dim_input),
        )
        return probe.shape[1]

    def extra_loss(self, index: np.ndarray, obs: dict, visual: torch.Tensor):
        """A further term of the regression loss on the batch of states `index` (`obs`, the
        student's visual encoding of them); None: none. For subclasses that train another
        head beside the student (e.g. `results/stage2/distill/chunks.py`)."""
        return None

    def batch_index(self, batch_size: int) -> np.ndarray:
        """The states of one regression batch, drawn from all data (`draw`)."""
        return self.draw(0, len(self.data), batch_size)

    def draw(self, low: int, high: int, size: int) -> np.ndarray:
        """`size` state indices from [low, high): uniform, or with the states near their target
        (`near_target_m`) `near_target_weight` times as likely as the others and those whose
        tip is near the target (`near_tip_m`) `near_tip_weight` times."""
        settings = self.config.distill
        if settings.near_target_weight == 1.0 and settings.near_tip_weight == 1.0:
            return self.rng.integers(low, high, size)  # the random stream of earlier runs
        cdf = self._cdf()
        start = cdf[low - 1] if low else 0.0
        drawn = np.searchsorted(cdf, self.rng.uniform(start, cdf[high - 1], size), side="right")
        return np.clip(drawn, low, high - 1)

    def _cdf(self) -> np.ndarray:
        if len(self._weights_cdf) != len(self.data):  # new states since it was built
            settings = self.config.distill
            goal = self.data.column("desired_goal")
            weights = np.ones(len(goal))
            if settings.near_target_weight != 1.0:
                clearance = target_clearance_m(goal, self.data.column("obstacles"))
                near = clearance < settings.near_target_m
                weights *= np.where(near, settings.near_target_weight, 1)
            if settings.near_tip_weight != 1.0:
                tip = np.linalg.norm(self.data.column("achieved_goal") - goal, axis=1)
                weights *= np.where(tip < settings.near_tip_m, settings.near_tip_weight, 1)
            self._weights_cdf = np.cumsum(weights)
        return self._weights_cdf

    def _pose_loss_on(self) -> bool:
        return self.vision and self.config.distill.pose_weight > 0

    def validate(self) -> dict[str, float]:
        """The deterministic student's rates on the first `num_eval_episodes` validation tasks."""
        seeds = VALIDATION_SEEDS.seeds(self.config.distill.num_eval_episodes)
        return summarize(evaluate(self.eval_env, SACPolicy(self.student), seeds))

    # --------------------------------------------------------------- files
    def policy_payload(self, iteration: int | str) -> dict[str, Any]:
        """The contents of the student's policy file after `iteration`."""
        state = self.student.state_dict()
        return {
            "format": ckpt.FORMAT,
            "kind": self.stage.policy_kind,
            "config": config_to_json(self.config.student),
            "env_steps": len(self.data),
            "distill_iteration": iteration,
            "agent": {k: state[k] for k in self.student.policy_state_keys()},
            **self.stage.policy_extras(self.student),
        }

    def _save(self, iteration: int | str, success: float) -> None:
        """The student after `iteration` (an index, or "final" once polished): its policy file,
        `policy.pt` if it is the best so far, and the state a rerun resumes from."""
        payload = self.policy_payload(iteration)
        name = "policy_final.pt" if iteration == "final" else f"policy_iteration{iteration}.pt"
        ckpt.save_torch(self.run_dir / name, payload)
        best = max(r["validation/success_rate"] for r in self._scored())
        if success >= best:
            ckpt.save_torch(self.run_dir / POLICY_NAME, payload)
        ckpt.save_torch(self.run_dir / STATE_NAME, self.resume_state())

    def resume_state(self) -> dict[str, Any]:
        """What a rerun resumes from (`load_resume_state`): weights, optimizer, random
        streams, the next episode seed and the history."""
        return {
            "format": ckpt.FORMAT,
            "kind": "distill",
            "iteration": self.history[-1]["iteration"],
            "final": self.final,
            **self.regression_state(),
            "next_seed": self.next_seed,
            "history": self.history,
            "lookahead_rng": self.lookahead.rng.bit_generator.state if self.lookahead else None,
            "noise_rng": self.noise_rng.bit_generator.state,
        }

    def regression_state(self) -> dict[str, Any]:
        """What `regress` changes: the student's, pose head's and added heads' weights, the
        optimizer and the batch stream (the student's state holds its own random generator)."""
        return {
            "student": self.student.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "pose_head": self.pose_head.state_dict(),
            "rng": self.rng.bit_generator.state,
            **{name: head.state_dict() for name, head in self.heads.items()},
        }

    def load_regression_state(self, state: dict[str, Any]) -> None:
        """Restore what `regression_state` saved."""
        self.student.load_state_dict(state["student"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.pose_head.load_state_dict(state["pose_head"])
        self.rng.bit_generator.state = state["rng"]
        for name, head in self.heads.items():
            head.load_state_dict(state[name])

    def load_resume_state(self, state: dict[str, Any]) -> None:
        """Restore what `resume_state` saved (the data is added by the caller)."""
        self.load_regression_state(state)
        self.next_seed = state["next_seed"]
        self.history = list(state["history"])
        self.final = state.get("final")
        if state.get("noise_rng") is not None:  # (absent from states saved before it existed)
            self.noise_rng.bit_generator.state = state["noise_rng"]
        if self.lookahead is not None and state.get("lookahead_rng") is not None:
            self.lookahead.rng.bit_generator.state = state["lookahead_rng"]

    def _resume(self) -> int:
        """The iteration to start from: 0, or the one after the last saved."""
        path = self.run_dir / STATE_NAME
        if not path.exists():
            return 0
        saved = json.loads((self.run_dir / "config.json").read_text())
        if _resumable_part(saved) != _resumable_part(json.loads(_config_json(self.config))):
            raise ValueError(
                f"{self.run_dir} holds a distillation with another configuration "
                "(config.json; only distill.iterations and distill.final_updates may change): "
                "use another --run-dir or the same options"
            )
        state = ckpt.load_torch(path, kind="distill")
        self.load_resume_state(state)
        if self.final is not None and self.config.distill.iterations > state["iteration"] + 1:
            raise ValueError(
                f"{self.run_dir} holds a polished student (distill.final_updates): it takes no "
                "more iterations; use another --run-dir"
            )
        for iteration in range(state["iteration"] + 1):
            self.data.add(ckpt.load_npz(self.run_dir / "data" / f"iteration{iteration}.npz"))
        print(f"resumed after iteration {state['iteration']} ({len(self.data)} samples)")
        return state["iteration"] + 1


def _config_json(config: DistillConfig) -> str:
    return (
        json.dumps(
            {
                "student": json.loads(config_to_json(config.student)),
                "distill": dataclasses.asdict(config.distill),
            },
            indent=2,
        )
        + "\n"
    )


def actor_features(agent, obs: dict, visual: torch.Tensor) -> torch.Tensor:
    """A student's actor features (what heads beside it read, `Distiller.add_head`) of a batch
    of observations `obs`, from their visual encoding `visual`."""
    return agent.actor_features(visual, agent.low_dim_input(obs))


def pose_loss(predicted: torch.Tensor, poses: torch.Tensor) -> torch.Tensor:
    """Mean squared error of predicted obstacle poses (B, N, 8) against the true ones under the
    best matching per sample (the obstacles' order carries no meaning)."""
    errors = [
        ((predicted[:, list(order)] - poses) ** 2).mean(dim=(1, 2))
        for order in itertools.permutations(range(poses.shape[1]))
    ]
    return torch.stack(errors).min(dim=0).values.mean()


def scale_lengths(poses: torch.Tensor, length_scale_m: float) -> torch.Tensor:
    """Obstacle poses (B, N, 8) with their lengths (centre, half sizes) in units of
    `length_scale_m`; the kinds' one-hot as it is."""
    scaled = poses.clone()
    scaled[..., POSE_LENGTHS] = poses[..., POSE_LENGTHS] / length_scale_m
    return scaled


def _resumable_part(config: dict) -> dict:
    """A config's JSON without what a resumed run may change (the number of iterations, the
    polishing); distill settings added after the run was written read as their defaults."""
    settings = {**dataclasses.asdict(DistillSettings()), **config["distill"]}
    return {**config, "distill": {**settings, "iterations": None, "final_updates": None}}


def distill(config: DistillConfig, show_progress: bool = True) -> dict[str, Any]:
    """Run the DAgger loop of `config`; the summary (best iteration and every iteration)."""
    return Distiller(config).run(show_progress)
