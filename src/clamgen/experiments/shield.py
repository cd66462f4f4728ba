"""A collision shield for a distilled vision student (beyond the paper).

A vision student distilled with the pose loss (`clamgen.experiments.distill`, `pose_weight`)
has a linear head that reads the obstacles' poses (kind, centre, half sizes) from its visual
encoding, to about 3 cm. The shield places those predicted obstacles, enlarged by
`margin_m`, in a scene of its own and checks the student's next joint step along its path, as
the env does. A step that keeps its clearance (stays `margin_m` away from every predicted
obstacle, or does not come closer when it already is nearer) is taken unchanged. Otherwise
the shield takes the nearest of a fixed set of alternatives (the action shortened, and fixed
perturbations of it before the tanh) that keeps its clearance, or, when none does, the one
that keeps the most. The table's pose is known exactly and is checked without margin.

Nothing privileged is read: the obstacles come from the student's own images.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from clamgen.envs.reach_env import (
    COLLISION_CHECK_RESOLUTION_RAD,
    MAX_JOINT_DELTA_RAD,
    step_target,
)
from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.distill import POSE_LENGTHS, POSE_SIZE, STATE_NAME
from clamgen.robot import ur5
from clamgen.sim import constants as C
from clamgen.sim.scene import Obstacles, Scene

MARGIN_M = 0.03
"""Clearance the shield keeps from predicted obstacles: about the pose head's error."""
NUM_PERTURBATIONS = 16
"""Fixed perturbations of the action (before the tanh) among the alternatives."""
PERTURBATION_STD = 1.0
"""Their standard deviation, in pre-tanh units (an action saturates near 3)."""
SHORTENED = (0.5, 0.25, 0.0)
"""Fractions of the action among the alternatives (0: stay)."""
MIN_HALF_SIZE_M = 0.005
"""Predicted half sizes are clipped to at least this."""
PRE_SQUASH_CLIP = 3.0
ALTERNATIVE_BATCHES = (1, 3, 7)
"""`choose_action` checks its alternatives nearest first, in batches split at these positions
(the nearest alone, the next two, the next four, the rest), and stops at the first batch
with one that keeps the clearance."""
SLIDE_ITERATIONS = 3
SLIDE_EPS_RAD = 1e-3
"""Finite-difference step of the clearance's gradient."""
SLIDE_EXTRA_M = 0.002
"""A slid step aims this far past the clearance it must keep (the gradient is local)."""


def predicted_obstacles(poses: np.ndarray, length_scale_m: float) -> Obstacles:
    """Obstacles from the pose head's (N, 8) output: kind by the larger of the one-hot pair,
    lengths rescaled to metres, half sizes at least `MIN_HALF_SIZE_M`."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, POSE_SIZE)
    lengths = poses[:, POSE_LENGTHS] * length_scale_m
    kinds = np.where(poses[:, 0] >= poses[:, 1], C.OBSTACLE_BOX, C.OBSTACLE_CYLINDER)
    half = np.maximum(lengths[:, 3:], MIN_HALF_SIZE_M)
    # A cylinder's half sizes are (radius, radius, half height).
    cylinder = kinds == C.OBSTACLE_CYLINDER
    half[cylinder, 1] = half[cylinder, 0]
    return Obstacles(kinds.astype(np.int64), lengths[:, :3].copy(), half)


class ClearanceChecker:
    """A scene of its own with the obstacles enlarged by `margin_m` on every side (the table as
    it is); the clearance of a joint step along its path. (Enlarged shapes rather than MuJoCo's
    contact margin: box-capsule contacts within a margin are not reported.)"""

    def __init__(self, margin_m: float = MARGIN_M) -> None:
        if not 0 <= margin_m < float("inf"):
            raise ValueError(f"margin_m must be a number >= 0, got {margin_m}")
        self.margin_m = margin_m
        self.scene = Scene(0.0)
        self._obstacle_geoms = self.scene.obstacle_geoms.ravel()

    def set_obstacles(self, obstacles: Obstacles) -> None:
        enlarged = Obstacles(
            obstacles.kinds, obstacles.positions_m, obstacles.half_sizes_m + self.margin_m
        )
        self.scene.set_obstacles(enlarged)

    def clearance(self, joints: np.ndarray) -> float:
        """Distance (m) of the arm at `joints` to the table or an obstacle (negative: touching),
        capped at `margin_m`: beyond the margin the enlarged obstacles are not touched. Within
        it, the depth into an enlarged obstacle approximates the distance to the obstacle
        (at a box's edges and corners the enlarged box is larger than the margin's reach, so
        the shield errs on the side of caution)."""
        scene = self.scene
        scene.data.qpos[:] = joints
        mujoco.mj_kinematics(scene.model, scene.data)
        mujoco.mj_collision(scene.model, scene.data)
        n = scene.data.ncon
        if n == 0:
            return self.margin_m
        contact = scene.data.contact
        obstacle = np.isin(contact.geom1[:n], self._obstacle_geoms) | np.isin(
            contact.geom2[:n], self._obstacle_geoms
        )
        distances = contact.dist[:n] + np.where(obstacle, self.margin_m, 0.0)
        return float(min(self.margin_m, distances.min()))

    def clearances(self, joints: np.ndarray) -> np.ndarray:
        return np.array([self.clearance(q) for q in joints])

    def step_clearance(self, joints: np.ndarray, action: np.ndarray) -> float:
        return step_clearance(self, joints, action)

    def step_clearances(self, joints: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return np.array([step_clearance(self, joints, a) for a in actions])


def step_checks(joints: np.ndarray, action: np.ndarray) -> np.ndarray:
    """The configurations (K, 6) the env checks along its straight joint step for `action`,
    the step's end last."""
    return checks_to(joints, step_target(joints, action))


def checks_to(joints: np.ndarray, target: np.ndarray) -> np.ndarray:
    """`step_checks` of the step from `joints` that ends at `target` (`step_target`)."""
    delta = target - joints
    checks = max(1, int(np.ceil(np.max(np.abs(delta)) / COLLISION_CHECK_RESOLUTION_RAD)))
    return joints + (np.arange(1, checks + 1) / checks)[:, None] * delta


def step_checks_many(joints: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`step_checks` of each of actions (A, 6) in one array (the same configurations, the
    same order), and where each action's checks start in it: (K, 6), (A,)."""
    delta = step_target(joints, actions) - joints  # (A, 6)
    counts = np.maximum(
        1, np.ceil(np.abs(delta).max(axis=1) / COLLISION_CHECK_RESOLUTION_RAD).astype(np.int64)
    )
    starts = np.concatenate([[0], np.cumsum(counts[:-1])])
    owner = np.repeat(np.arange(len(counts)), counts)
    fraction = (np.arange(len(owner)) - starts[owner] + 1) / counts[owner]
    return joints + fraction[:, None] * delta[owner], starts


def step_clearance(checker, joints: np.ndarray, action: np.ndarray) -> float:
    """Smallest `checker.clearance` along the env's straight joint step for `action`."""
    return min(checker.clearance(q) for q in step_checks(joints, action))


def perturbations(seed: int = 0) -> np.ndarray:
    """The fixed perturbations (before the tanh) among a shield's alternatives."""
    rng = np.random.default_rng(seed)
    return PERTURBATION_STD * rng.standard_normal((NUM_PERTURBATIONS, ur5.NUM_JOINTS))


def slide(checker, joints: np.ndarray, action: np.ndarray, keep: float) -> np.ndarray:
    """`action` with its motion into the obstacles taken out: the least change of the step's
    end that brings its clearance back to `keep`, on the clearance's gradient there (finite
    differences), repeated `SLIDE_ITERATIONS` times. The arm then slides along an obstacle
    instead of stopping at it."""
    low, high = ur5.JOINT_LIMITS.T
    target = step_target(joints, action)
    for _ in range(SLIDE_ITERATIONS):
        now = checker.clearance(target)
        if now >= keep:
            break
        moved = checker.clearances(target + np.eye(len(target)) * SLIDE_EPS_RAD)
        gradient = (moved - now) / SLIDE_EPS_RAD
        norm2 = float(gradient @ gradient)
        if norm2 < 1e-12:
            break
        target = np.clip(target + (keep - now + SLIDE_EXTRA_M) * gradient / norm2, low, high)
    return np.clip((target - joints) / MAX_JOINT_DELTA_RAD, -1.0, 1.0)


def choose_action(
    checker,
    joints: np.ndarray,
    action: np.ndarray,
    pre: np.ndarray,
    offsets: np.ndarray,
    sliding: bool = False,
) -> tuple[np.ndarray, bool]:
    """The shield's choice for `action` (`pre`: before the tanh) at `joints`, and whether it
    replaced it. `checker` has `margin_m`, `clearance(joints)` (capped at the margin),
    `clearances` of a batch of joints, and `step_clearance(joints, action)` (the smallest
    along the step) and `step_clearances` of a batch of actions.

    A step that keeps its clearance (stays `margin_m` away, or does not come closer when it
    already is nearer) is taken unchanged; otherwise the nearest alternative (the action
    shortened, `tanh(pre + offsets)`) that keeps it, or, when none does, the one that keeps
    the most. Staying keeps the clearance exactly, so some alternative always passes. With
    `sliding`, the action with its motion into the obstacles taken out (`slide`, the least
    change that keeps the clearance) is tried first."""
    step = checker.step_clearance(joints, action)
    if step >= checker.margin_m:  # (the usual case, and no need to know the clearance now)
        return np.asarray(action, dtype=np.float32), False
    keep = min(checker.clearance(joints), checker.margin_m)
    if step >= keep:
        return np.asarray(action, dtype=np.float32), False
    if sliding:
        slid = slide(checker, joints, action, keep)
        if checker.step_clearance(joints, slid) >= keep:
            return slid.astype(np.float32), True
    pre = np.clip(pre, -PRE_SQUASH_CLIP, PRE_SQUASH_CLIP)
    shortened = np.asarray(SHORTENED)[:, None] * np.asarray(action)
    alternatives = np.concatenate([shortened, np.tanh(pre + offsets)])
    distances = np.linalg.norm(alternatives - action, axis=1)
    # Nearest first, in growing batches: the first that keeps the clearance is the choice
    # (the nearest that does, ties to the earlier alternative), usually in the first batch.
    order = np.argsort(distances, kind="stable")
    clearances = np.full(len(alternatives), -np.inf)
    for batch in np.split(order, ALTERNATIVE_BATCHES):
        clearances[batch] = checker.step_clearances(joints, alternatives[batch])
        ok = batch[clearances[batch] >= keep]
        if len(ok):
            return alternatives[ok[0]].astype(np.float32), True
    return alternatives[int(np.argmax(clearances))].astype(np.float32), True


class ShieldedStudent:
    """A distilled vision student acting through the collision shield (a `Policy`).

    `agent`: the student (`ResidualAgent` with images); `pose_head`: its trained pose head
    (a `torch.nn.Linear` from the visual encoding to N x 8). Counts `num_shielded` steps.
    """

    def __init__(
        self,
        agent,
        pose_head: torch.nn.Module,
        length_scale_m: float = 1.0,
        margin_m: float = MARGIN_M,
        seed: int = 0,
        true_poses: bool = False,
    ) -> None:
        self.agent = agent
        self.true_poses = true_poses
        self.pose_head = pose_head.eval()
        self.length_scale_m = length_scale_m
        self.checker = ClearanceChecker(margin_m)
        self.perturbations = perturbations(seed)
        self.num_steps = 0
        self.num_shielded = 0

    def reset(self, env: Any | None = None) -> None:
        pass

    @torch.inference_mode()
    def act(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        agent = self.agent
        batch = {k: np.asarray(v)[None] for k, v in obs.items() if k != "obstacles"}
        visual = agent.critic.encoder(agent.encoder_input(batch))
        pre = agent.policy_mean(visual, agent.low_dim_input(batch))[0].numpy()
        poses = self.pose_head(visual).view(-1, POSE_SIZE).numpy()
        action = np.tanh(pre)
        self.num_steps += 1
        joints = np.asarray(obs["observation"], dtype=np.float64)[: ur5.NUM_JOINTS]
        if self.true_poses:  # an oracle, to measure the shield apart from the pose head
            self.checker.set_obstacles(predicted_obstacles(obs["obstacles"], 1.0))
        else:
            self.checker.set_obstacles(predicted_obstacles(poses, self.length_scale_m))
        # With true poses the shield never lets the arm touch an obstacle.
        chosen, shielded = choose_action(self.checker, joints, action, pre, self.perturbations)
        self.num_shielded += int(shielded)
        return chosen


def load_shielded_student(
    run_dir: str | Path, margin_m: float = MARGIN_M, seed: int = 0, true_poses: bool = False
) -> tuple[ShieldedStudent, dict]:
    """The student of a distillation (or `offline.py`) run directory with its pose head, from
    the run's `student.pt` (the last iteration's student: the pose head was trained with it),
    and the env options it observes with."""
    import json

    from clamgen.experiments.stage2 import load_residual_agent

    run_dir = Path(run_dir)
    state = ckpt.load_torch(run_dir / STATE_NAME, kind=None)
    agent, config = load_residual_agent(run_dir / "policy.pt")
    agent.load_state_dict(state["student"])
    head = state["pose_head"]
    pose_head = torch.nn.Linear(head["weight"].shape[1], head["weight"].shape[0])
    pose_head.load_state_dict(head)
    settings = json.loads((run_dir / "config.json").read_text())["distill"]
    kwargs = config.env.make_kwargs()
    kwargs.pop("target_speed")
    if true_poses:
        kwargs["include_obstacle_state"] = True
    policy = ShieldedStudent(
        agent, pose_head, settings.get("pose_length_scale_m", 1.0), margin_m, seed, true_poses
    )
    return policy, kwargs
