"""A privileged teacher that looks ahead in the simulator before it acts (beyond the paper).

The privileged residual acts in one forward pass; on blocked-path tasks it still collides or
stalls on about a quarter of them (`results/stage2/tune/README.md`). A teacher for
distillation need not act fast and may use the simulator itself, so this one plans:

1. it keeps a plan per episode: offsets (horizon, 6) added to the residual's pre-squash mean,
   all zero at the start (the residual's own behaviour);
2. before each step it rolls the residual, with the plan's offsets, forward in a copy of the
   simulator (true obstacles, true contact) until it reaches the goal, collides, or runs out
   of horizon;
3. if that rollout reaches the goal without a collision, it keeps the plan; if not, it rolls
   out `candidates` perturbed plans (the plan, and no plan, plus piecewise-constant Gaussian
   offsets in `segments` pieces) and keeps the best: a collision-free arrival, the earliest
   first; then no collision, the closest final distance; a collision last;
4. it acts (or labels, for the student) with the residual's mean plus the plan's first offset,
   and shifts the plan by one step.

With `fixed_offsets` the perturbed plans' offsets are drawn once, a fixed library of
candidates, instead of anew at every search. The teacher then chooses among the same plans at
nearby states, so its labels are a consistent function of the state: with fresh draws, two
nearby states may be labelled "pass left" and "pass right" by chance, and a student regressing
both learns their average, which runs into the obstacle.

Labelling a student's states, the teacher may also prefer the student's own choice
(`prefer`): where a search runs, the clean arrival whose first action is nearest to the
student's action wins instead of the earliest. Where the obstacle can be passed on either side,
the label then keeps the side the student already takes instead of the side a random search
found first, so that its labels at nearby states do not pull both ways (DAgger with a
multimodal expert).

With `least_offset`, a search keeps the clean arrival whose offsets deviate least from the
residual's own actions (the smallest norm over the plan; no offset at all when the residual
alone arrives) instead of the earliest arrival. An earliest arrival is the argmax of a score
that nearby states reorder by a step or two, so their labels jump between candidates with
unrelated offsets; the least deviation is a fixed order over the library's zero-centred plans
and labels near the residual's own action wherever a small bend suffices. (Privileged students
of it did better, but their regression losses were no lower:
`results/stage2/distill/README.md`, "A teacher that bends least".)

With a clearance `margin_m` > 0 the rollouts count any approach closer than that to an
obstacle or the table as a collision (the planning envs' `collision_margin_m`), so the plans it
keeps pass obstacles with room to spare; where no candidate keeps the clearance (a goal close
to an obstacle, or a state already within it), it plans again against true contact. A student
imitating clear plans has that room for its own errors.

The rollouts are closed-loop: the residual still reacts to each state, the offsets only bend
it. Since the simulator is deterministic, a plan that was seen to arrive stays valid while the
teacher itself drives along it, and is not rolled out again. A student imitates the teacher's
labels (`clamgen distill --distill.lookahead-candidates`); the teacher's own success is what
`LookaheadPolicy` measures.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from clamgen.envs.reach_env import MAX_EPISODE_STEPS, EnvState, ReachEnv

# Labels and rollouts clip the pre-squash action to this (tanh(3) = 0.995, a saturated step);
# the distillation labels (`distill.TARGET_CLIP`) use it too.
PRE_SQUASH_CLIP = 3.0
# Ranking of rollout outcomes (larger is better): a collision-free arrival scores ARRIVAL minus
# its step count, a collision-free miss minus its final distance (m), a collision COLLISION
# minus its final distance.
ARRIVAL_SCORE = 1000.0
COLLISION_SCORE = -1000.0
# Defaults (those of every measured run): perturbed plans per search, steps per rollout (an
# arrival past an obstacle takes 10-40 steps), offset std before the tanh, offset pieces.
CANDIDATES = 16
HORIZON = 40
NOISE = 1.0
SEGMENTS = 2
# Default clearance of the plans (m): 0, true contact (the measured runs before the clearance).
MARGIN_M = 0.0


@dataclass(frozen=True)
class Outcome:
    """What one rollout did: steps until it arrived (None: never), whether it collided, and
    the tip's final distance to the target (m)."""

    arrived_after: int | None
    collided: bool
    final_distance_m: float

    @property
    def clean(self) -> bool:
        return self.arrived_after is not None and not self.collided

    def score(self) -> float:
        if self.collided:
            return COLLISION_SCORE - self.final_distance_m
        if self.arrived_after is not None:
            return ARRIVAL_SCORE - self.arrived_after
        return -self.final_distance_m


class LookaheadTeacher:
    """A privileged residual (`ResidualAgent` with `agent.obs_source 'obstacles'`) that plans
    with rollouts of itself; see the module docstring.

    Args:
        agent: the privileged residual.
        num_obstacles: obstacles per task (the planning envs take everything else from the
            states they are given).
        candidates: perturbed plans rolled out when the current plan does not arrive (>= 1).
        horizon: steps per rollout (the episode's remaining steps, if fewer).
        noise: standard deviation of the offsets, in pre-squash units.
        segments: pieces of constant offset along the horizon.
        seed: seed of the offsets.
        margin_m: clearance (m) the plans keep from obstacles and the table where they can;
            0: true contact only.
        fixed_offsets: search one library of offsets drawn once instead of fresh draws.
        least_offset: a search keeps the clean arrival with the smallest offsets instead of
            the earliest (a student's preferred action, where `act` is given one, comes first).
    """

    def __init__(
        self,
        agent,
        num_obstacles: int,
        candidates: int = CANDIDATES,
        horizon: int = HORIZON,
        noise: float = NOISE,
        segments: int = SEGMENTS,
        seed: int = 0,
        margin_m: float = MARGIN_M,
        fixed_offsets: bool = False,
        least_offset: bool = False,
    ) -> None:
        if candidates < 1 or horizon < 1 or segments < 1 or not noise >= 0:
            raise ValueError(
                "lookahead needs candidates, horizon and segments >= 1 and noise >= 0, got "
                f"{candidates}, {horizon}, {segments}, {noise}"
            )
        if not 0 <= margin_m < float("inf"):
            raise ValueError(f"lookahead margin_m must be a number >= 0, got {margin_m}")
        self.agent = agent
        self.candidates = candidates
        self.horizon = horizon
        self.noise = noise
        self.segments = segments
        self.margin_m = float(margin_m)
        self.least_offset = least_offset
        self.rng = np.random.default_rng(seed)
        # The library of offsets every search uses with `fixed_offsets` (None: drawn anew).
        self.offsets = self._draw_offsets() if fixed_offsets else None
        self._env_kwargs = {
            "num_obstacles": num_obstacles,
            "include_obstacle_state": True,
            "max_episode_steps": None,
        }
        self._pools: dict[float, list[ReachEnv]] = {}  # planning envs by clearance
        self.rollouts = 0
        """Rollouts run so far (a cost counter)."""
        self.searches = 0
        """States at which the plan did not arrive and candidates were rolled out."""

    # ------------------------------------------------------------------ acting
    def new_plan(self) -> np.ndarray:
        return np.zeros((self.horizon, 6), dtype=np.float32)

    def act(
        self,
        state: EnvState,
        obs: dict[str, np.ndarray],
        plan: np.ndarray,
        known_clean: bool,
        prefer: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, bool]:
        """(label, next plan, next known_clean) at `state` (observation `obs`, unbatched).

        label: the pre-squash action (6,), clipped to +-PRE_SQUASH_CLIP; acting means
        tanh(label). known_clean: `plan` is already known to arrive without a collision from
        this state (the teacher drove here along it); the returned flag says the same of the
        next state, if the label is executed exactly. prefer: a pre-squash action (6,), the
        student's; when a search runs, the clean arrival whose first action is nearest to it
        wins instead of the earliest (None: the earliest)."""
        horizon = max(1, min(self.horizon, MAX_EPISODE_STEPS - state.num_steps))
        plan = plan[:horizon]
        batch = {k: v[None] for k, v in obs.items()}
        mean = self.agent.mean_action(batch)[0]
        wanted = None if prefer is None else prefer - mean
        if not known_clean:
            plan, outcome = self._plan(state, plan, self.margin_m, wanted)
            if not outcome.clean and self.margin_m > 0:
                plan, outcome = self._plan(state, plan, 0.0, wanted)
            known_clean = outcome.clean
        label = np.clip(mean + plan[0], -PRE_SQUASH_CLIP, PRE_SQUASH_CLIP)
        following = np.zeros((self.horizon, 6), dtype=np.float32)
        following[: len(plan) - 1] = plan[1:]
        # A plan that arrives this very step leaves nothing to know about the next state.
        return label.astype(np.float32), following, known_clean and len(plan) > 1

    def _plan(self, state: EnvState, plan: np.ndarray, margin_m: float, wanted=None):
        """(plan, its outcome): `plan` if it arrives cleanly with clearance `margin_m`, else the
        best of a search around it (`wanted`: the first offset preferred among clean arrivals)."""
        (outcome,) = self.rollout(state, plan[None], margin_m)
        if outcome.clean:
            return plan, outcome
        return self._search(state, plan, outcome, margin_m, wanted)

    def _search(
        self,
        state: EnvState,
        plan: np.ndarray,
        outcome: Outcome,
        margin_m: float,
        wanted: np.ndarray | None = None,
    ):
        self.searches += 1
        horizon = len(plan)
        cuts = np.linspace(0, horizon, self.segments + 1).round().astype(int)
        steps = np.repeat(np.arange(self.segments), np.diff(cuts))
        noise = self._draw_offsets() if self.offsets is None else self.offsets
        centres = np.where(np.arange(self.candidates)[:, None, None] % 2 == 0, plan[None], 0.0)
        perturbed = (centres + noise[:, steps]).astype(np.float32)
        plans = np.concatenate([np.zeros((1, horizon, 6), np.float32), perturbed])
        outcomes = self.rollout(state, plans, margin_m)
        clean = [i for i, o in enumerate(outcomes) if o.clean]
        if wanted is not None and clean:
            best = min(clean, key=lambda i: float(np.linalg.norm(plans[i, 0] - wanted)))
            return plans[best], outcomes[best]
        if self.least_offset and clean:
            best = min(clean, key=lambda i: float(np.linalg.norm(plans[i])))
            return plans[best], outcomes[best]
        best = int(np.argmax([o.score() for o in outcomes]))
        if outcomes[best].score() <= outcome.score():
            return plan, outcome
        return plans[best], outcomes[best]

    def _draw_offsets(self) -> np.ndarray:
        return self.rng.normal(0.0, self.noise, (self.candidates, self.segments, 6))

    # ------------------------------------------------------------------ rollouts
    def rollout(self, state: EnvState, plans: np.ndarray, margin_m: float = 0.0) -> list[Outcome]:
        """Roll the residual with each plan's offsets (C, H, 6) forward from `state`, all C in
        lockstep in planning envs that count contacts within `margin_m` as collisions; each
        stops when it arrives or collides."""
        count, horizon = plans.shape[:2]
        self.rollouts += count
        pool = self._pools.setdefault(margin_m, [])
        while len(pool) < count:
            pool.append(ReachEnv(**self._env_kwargs, collision_margin_m=margin_m))
        envs = pool[:count]
        observations = []
        for env in envs:
            env.set_state(state)
            observations.append(env.observe())
        arrived: list[int | None] = [None] * count
        collided = [False] * count
        start = observations[0]
        distance = [float(np.linalg.norm(start["achieved_goal"] - start["desired_goal"]))] * count
        active = list(range(count))
        for t in range(horizon):
            if not active:
                break
            batch = {k: np.stack([observations[i][k] for i in active]) for k in observations[0]}
            means = self.agent.mean_action(batch)
            actions = np.tanh(np.clip(means + plans[active, t], -PRE_SQUASH_CLIP, PRE_SQUASH_CLIP))
            still = []
            for j, i in enumerate(active):
                observations[i], _, _, _, info = envs[i].step(actions[j])
                distance[i] = float(info["distance_m"])
                if info["collision"]:
                    collided[i] = True
                elif info["is_success"]:
                    arrived[i] = t + 1
                else:
                    still.append(i)
            active = still
        return [Outcome(arrived[i], collided[i], distance[i]) for i in range(count)]

    def close(self) -> None:
        for pool in self._pools.values():
            for env in pool:
                env.close()
        self._pools.clear()


class LookaheadPolicy:
    """A `LookaheadTeacher` following one episode's plan in an env, as an evaluation `Policy`
    (`reset(env)`, `act`) and as the distillation's labeller (`label`, `off_plan`); it reads
    the env's state at each step."""

    def __init__(self, teacher: LookaheadTeacher) -> None:
        self.teacher = teacher
        self.deterministic = True
        self._env: Any = None
        self._plan = teacher.new_plan()
        self._known_clean = False

    def reset(self, env: Any | None = None) -> None:
        self._env = env
        self._plan = self.teacher.new_plan()
        self._known_clean = False

    def label(self, obs: dict[str, np.ndarray], prefer: np.ndarray | None = None) -> np.ndarray:
        """The teacher's pre-squash action (6,) at the env's current state (observation `obs`;
        `prefer`: the student's pre-squash action, `LookaheadTeacher.act`); the plan moves on
        by one step."""
        if self._env is None:
            raise RuntimeError("LookaheadPolicy.reset(env) must be called before act or label")
        state = self._env.unwrapped.get_state()
        label, self._plan, self._known_clean = self.teacher.act(
            state, obs, self._plan, self._known_clean, prefer
        )
        return label

    def off_plan(self) -> None:
        """Another action than the label is about to be executed: the next state is off the
        plan's path, so the plan is rolled out again there."""
        self._known_clean = False

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.tanh(self.label(obs))
