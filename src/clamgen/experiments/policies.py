"""Policies by name, for the command line: shipped checkpoints, policy files, baselines."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from clamgen.experiments.checkpoint import SHIPPED_POLICIES, resolve_policy_path
from clamgen.policy import Policy

DEPTH_RRT_BASELINES = {"depth-rrt-3views": 3, "depth-rrt-2views": 2, "depth-rrt-1view": 1}
"""RRT on the depth map of that many rendered views, no learned policy
(`depth_planner.depth_rrt`), by name."""
BASELINES = ("ik", "rrt", *DEPTH_RRT_BASELINES)
# The names above, as a type: command-line options typed `PolicyName | Path` list them.
PolicyName = Literal[
    "base",
    "residual-3views",
    "residual-2views",
    "residual-1view",
    "image-only",
    "ik",
    "rrt",
    "depth-rrt-3views",
    "depth-rrt-2views",
    "depth-rrt-1view",
]

__all__ = [
    "BASELINES",
    "DEPTH_RRT_BASELINES",
    "SHIPPED_POLICIES",
    "PolicyName",
    "load_policy",
    "policy_label",
    "policy_observation",
    "resolve_policy_path",
    "views_suffix",
]


def load_policy(name: str | Path, **depth_rrt_options) -> tuple[Policy, str, dict]:
    """A policy, a description of where it came from, and the env options it observes with.

    `name`: "ik" (IK interpolation), "rrt" (OMPL RRTConnect with the full scene model),
    "depth-rrt-3views" / "-2views" / "-1view" (RRT-Connect on the depth map of that many
    rendered views, no learned policy: `depth_planner.depth_rrt`), "base" (the shipped joint
    policy), a shipped vision policy, or the path of a policy file from `clamgen train` or
    `clamgen train-residual`. The env options (views, image size, obstacle poses) are those
    the policy was trained with, or the views the depth baselines plan on; the other
    baselines and joint policies need none. `depth_rrt_options` (`plan_checks`, `track_m`,
    `noise_m`) go to `depth_planner.depth_rrt` for a depth baseline (TypeError for others).
    Raises `clamgen.experiments.checkpoint.CheckpointError` for a bad policy file.
    """
    if depth_rrt_options and name not in DEPTH_RRT_BASELINES:
        raise TypeError(f"depth_rrt_options are for {sorted(DEPTH_RRT_BASELINES)}, not {name}")
    if name == "ik":
        from clamgen.baselines import IKInterpolationPolicy

        return IKInterpolationPolicy(), "ik_interpolation", {}
    if name == "rrt":
        from clamgen.baselines import RRTPolicy

        return RRTPolicy(), "rrt_connect", {}
    if name in DEPTH_RRT_BASELINES:
        from clamgen.experiments.depth_planner import depth_rrt

        policy, env_kwargs = depth_rrt(DEPTH_RRT_BASELINES[name], **depth_rrt_options)
        return policy, f"{name} (RRT-Connect on the depth map, no learned policy)", env_kwargs
    from clamgen.experiments import checkpoint as ckpt
    from clamgen.experiments.evaluate import SACPolicy
    from clamgen.experiments.train import load_policy_agent

    path = resolve_policy_path(name)
    source = f"{name} ({SHIPPED_POLICIES[name]})" if name in SHIPPED_POLICIES else str(path)
    payload = ckpt.load_torch(path, kind=None)  # read once, whichever stage wrote it
    if payload.get("kind") == "residual-policy":
        from clamgen.experiments.stage2 import load_residual_agent

        agent, config = load_residual_agent(path, payload)
        kwargs = config.env.make_kwargs()
        kwargs.pop("target_speed")
        return SACPolicy(agent), source, kwargs
    agent, _ = load_policy_agent(path, payload)
    return SACPolicy(agent), source, {}


def views_suffix(num_views: int) -> str:
    """How policy and result names spell a number of views: "3views", "2views", "1view"."""
    return f"{num_views}view{'s' * (num_views != 1)}"


def policy_observation(policy: Policy) -> str:
    """What a policy's networks see, as the paper's Table 1 names it: "joints" (joints and
    goal), "images" (camera views only: the image-only policy) or "joints+images"."""
    config = getattr(getattr(policy, "agent", None), "config", None)
    if getattr(config, "obs_source", None) != "images":
        return "joints"
    return "joints+images" if config.use_low_dim else "images"


def policy_label(name: str | Path) -> str:
    """The policy's name in default output file names and captions: a shipped policy's or
    baseline's own name; for a run's policy file (RUN_DIR/policy.pt) the run directory's name,
    with its parent's for a seed directory (sweeps: ROW/seed0/policy.pt -> ROW_seed0); else
    the file's stem."""
    if name in (*SHIPPED_POLICIES, *BASELINES):
        return str(name)
    path = Path(name).absolute()
    if path.name != "policy.pt":
        return path.stem
    run = path.parent
    return f"{run.parent.name}_{run.name}" if re.fullmatch(r"seed\d+", run.name) else run.name
