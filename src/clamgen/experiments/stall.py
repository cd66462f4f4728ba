"""Stalls: steps since the tip last came nearer its target, and a policy that switches on them
(beyond the paper).

A distilled vision student that fails a blocked-path task without a collision has mostly
stalled: it came within a few centimetres of the target and then hovered there, commanding
small steps, until the time limit. From those very states the students' teacher (the
lookahead in the simulator) arrives on nearly every one, with a saturated joint command that
takes the arm around whatever holds it (`results/stage2/ensemble/README.md`). Whether a state
is such a stall is plain from the episode, not from one image: the tip has not come nearer for
many steps.

Two rules tell a stall, both here. `ProgressWindow` is the hybrid planner's
(`depth_planner.DepthShieldPlanner` plans when it fires): the tip is not `WINDOW_PROGRESS_M`
nearer the target than it was `WINDOW_STEPS` steps before, and not at the target. It forgets an
episode's history at each plan, so that the path the planner hands over gets its own window.
`stall_counts` counts, for each state of one episode, the steps since the tip last came
`PROGRESS_M` nearer the target than ever before in the episode (a count, for a switch at any
threshold, that a step back from the best does not reset);
`StallCounter` counts the same online; `pool_stall_counts` over pooled distillation data (whose
parallel episodes are interleaved). `StallSwitch` acts with one policy and hands over to
another (e.g. an *escape* student, regressed on the stalled states of the distillation data
only: `offline.py --stalled-only`) while the count is at least `after_steps`. Measured for the
3-view students (session 28), such a switch did not help: the escape student, like the students
themselves, fits the way out of the stalls in its data but does not carry it to new tasks'
stalls. `StallBurst` leaves a stall at random instead: a few steps of one random joint command,
then the policy again from wherever they took the arm (the random escapes of randomized
potential-field planners), needing nothing but the observation's tip and target.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from clamgen.robot import ur5

PROGRESS_M = 0.005
"""A step makes progress when the tip is this much nearer the target than it has been before in
the episode (a quarter of the 2 cm success radius)."""
AFTER_STEPS = 10
"""Default count at which `StallSwitch` hands over: an episode that arrives takes about 20
steps, nearly all of them nearer than the last."""
BURST_STEPS = 5
"""`StallBurst`: steps of one random command per escape (at most 0.25 rad a joint)."""
BURST_SCALE = 1.0
"""`StallBurst`: each joint's random command is uniform in [-scale, scale] (of the action's
range, `MAX_JOINT_DELTA_RAD` a step)."""


ESCAPES_BEFORE_PLAN = 0
"""With a planner around `StallBurst` (`depth_planner.DepthGuard(planner=True, escapes=True)`):
the escapes an episode begins before the planner may plan. 0, the planner first and the
escapes where it finds no path: chosen over 1 on validation tasks in session 41 (as many or
more blocked successes for 3, 2 and 1 views; `results/stage2/shield/README.md`)."""


WINDOW_STEPS = 10
"""`ProgressWindow`: steps without `WINDOW_PROGRESS_M` of progress before a stall (the hybrids'
test rows were measured with 10 and 1 cm)."""
WINDOW_PROGRESS_M = 0.01


def tip_distance(obs: dict[str, np.ndarray]) -> float:
    return float(np.linalg.norm(np.asarray(obs["achieved_goal"]) - obs["desired_goal"]))


class ProgressWindow:
    """The hybrid planner's stall rule, online: `stalled(distance)` at each state of an episode,
    the tip's distance to its target there, is True once the tip is not `progress_m` nearer
    than it was `steps` states before, while it is farther than `arrived_m` (at the target, a
    hovering tip has arrived, not stalled). `restart()` forgets all but the latest distance (a
    new window after a plan); `reset()` at an episode's start."""

    def __init__(
        self, steps: int = WINDOW_STEPS, progress_m: float = WINDOW_PROGRESS_M, arrived_m=0.0
    ) -> None:
        if steps < 1:
            raise ValueError(f"stuck_steps must be >= 1, got {steps}")
        self.steps, self.progress_m, self.arrived_m = steps, progress_m, arrived_m
        self.reset()

    def reset(self) -> None:
        self.distances: list[float] = []

    def restart(self) -> None:
        self.distances = self.distances[-1:]

    def stalled(self, distance: float) -> bool:
        d = self.distances
        d.append(float(distance))
        return (
            len(d) > self.steps
            and d[-1] > self.arrived_m
            and d[-1 - self.steps] - d[-1] < self.progress_m
        )


class StallCounter:
    """The stall count of an episode as it goes: `count(distance)` (or `update(obs)`) at each of
    its states, the tip's distance to the target there, gives the steps since the last state
    that made progress (`PROGRESS_M`; the first state counts 0); `reset()` at its start."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._best, self._last, self._t = np.inf, 0, -1

    def count(self, distance: float) -> int:
        self._t += 1
        if distance < self._best - PROGRESS_M:
            self._best, self._last = distance, self._t
        return self._t - self._last

    def update(self, obs: dict[str, np.ndarray]) -> int:
        return self.count(tip_distance(obs))


def stall_counts(distances: np.ndarray) -> np.ndarray:
    """(T,) `StallCounter`'s count at each state of one episode (the tip's distances to the
    target, in step order)."""
    counter = StallCounter()
    return np.array([counter.count(d) for d in np.asarray(distances, np.float64)], np.int64)


def pool_episodes(obstacles: np.ndarray, file_lengths: list[int]) -> np.ndarray:
    """(N,) an episode number for each row of pooled distillation data. A collection writes the
    states of its parallel episodes interleaved, each episode's in step order, and every task of
    a run has its own seed: within one data file, the rows with the same obstacles are one
    episode. `file_lengths`: the rows of each data file, in pool order."""
    if sum(file_lengths) != len(obstacles):
        raise ValueError(f"files hold {sum(file_lengths)} rows, the pool {len(obstacles)}")
    flat = np.ascontiguousarray(obstacles).reshape(len(obstacles), -1)
    files = np.repeat(np.arange(len(file_lengths), dtype=np.int64), file_lengths)
    keys = np.concatenate([flat.view(np.uint8), files[:, None].view(np.uint8)], axis=1)
    _, episode = np.unique(keys, axis=0, return_inverse=True)
    return episode.reshape(-1)


def episode_rows(episode: np.ndarray) -> list[np.ndarray]:
    """The rows of each episode (numbers as `pool_episodes` gives them), each in step order."""
    order = np.argsort(episode, kind="stable")
    return np.split(order, np.flatnonzero(np.diff(episode[order])) + 1)


def pool_stall_counts(
    achieved: np.ndarray, desired: np.ndarray, obstacles: np.ndarray, file_lengths: list[int]
) -> np.ndarray:
    """(N,) `stall_counts` of every row of pooled distillation data (`pool_episodes`)."""
    distances = np.linalg.norm(np.asarray(achieved) - np.asarray(desired), axis=1)
    counts = np.empty(len(distances), np.int64)
    for rows in episode_rows(pool_episodes(obstacles, file_lengths)):
        counts[rows] = stall_counts(distances[rows])
    return counts


class StallSwitch:
    """`policy` acting, `escape` instead while the stall count (`StallCounter`) is at least
    `after_steps` (a `Policy`). Counts `num_escape_steps` of `num_steps`."""

    def __init__(self, policy, escape, after_steps: int = AFTER_STEPS) -> None:
        if after_steps < 1:
            raise ValueError(f"after_steps must be >= 1, got {after_steps}")
        self.policy = policy
        self.escape = escape
        self.after_steps = after_steps
        self.counter = StallCounter()
        self.num_steps = 0
        self.num_escape_steps = 0

    @property
    def agent(self):
        return getattr(self.policy, "agent", None)

    def reset(self, env: Any | None = None) -> None:
        self.counter.reset()
        self.policy.reset(env)
        self.escape.reset(env)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        self.num_steps += 1
        if self.counter.update(obs) >= self.after_steps:
            self.num_escape_steps += 1
            return self.escape.act(obs)
        return self.policy.act(obs)


class StallBurst:
    """`policy` acting, with random escapes from stalls: once the stall count (`StallCounter`)
    reaches `after_steps`, `burst_steps` steps of one random command (each joint uniform in
    [-`scale`, `scale`]), then `policy` again for at least `after_steps` steps before the next
    burst (if the count has not restarted by then). The random stream restarts from `seed` at
    each reset, so an episode acts the same every time. `choose(rng, obs)`, if given, draws a
    burst's command instead (from the same stream; e.g. among random candidates by what a
    depth map shows). Counts `num_burst_steps` of `num_steps`, and `episode_bursts`, the bursts
    begun in the current episode."""

    def __init__(
        self,
        policy,
        after_steps: int = AFTER_STEPS,
        burst_steps: int = BURST_STEPS,
        scale: float = BURST_SCALE,
        seed: int = 0,
        choose=None,
    ) -> None:
        if after_steps < 1 or burst_steps < 1:
            raise ValueError(
                f"after_steps and burst_steps must be >= 1, got {after_steps}, {burst_steps}"
            )
        if not 0.0 < scale <= 1.0:
            raise ValueError(f"scale must be in (0, 1], got {scale}")
        self.policy = policy
        self.after_steps = after_steps
        self.burst_steps = burst_steps
        self.scale = scale
        self.seed = seed
        self.choose = choose
        self.counter = StallCounter()
        self.num_steps = 0
        self.num_burst_steps = 0
        self._restart()

    @property
    def agent(self):
        return getattr(self.policy, "agent", None)

    def reset(self, env: Any | None = None) -> None:
        self.policy.reset(env)
        self._restart()

    def _restart(self) -> None:
        self.counter.reset()
        self._rng = np.random.default_rng(self.seed)
        self._command = np.zeros(ur5.NUM_JOINTS)
        self._left = 0  # steps of the current burst still to take
        self._since = self.after_steps  # policy steps since the last burst ended
        self.episode_bursts = 0

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        self.num_steps += 1
        count = self.counter.update(obs)
        if not self._left and count >= self.after_steps and self._since >= self.after_steps:
            if self.choose is None:
                self._command = self._rng.uniform(-self.scale, self.scale, ur5.NUM_JOINTS)
            else:
                self._command = np.asarray(self.choose(self._rng, obs), np.float64)
            self._left = self.burst_steps
            self.episode_bursts += 1
        if self._left:
            self._left -= 1
            self._since = 0
            self.num_burst_steps += 1
            return self._command.astype(np.float32)
        self._since += 1
        return self.policy.act(obs)
