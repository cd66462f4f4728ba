"""Policies by name, for the command line: shipped checkpoints, policy files, baselines."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from clamgen.policy import Policy

# Policies shipped inside the package (clamgen/checkpoints/).
SHIPPED_POLICIES = {"base": "base.pt"}
BASELINES = ("ik", "rrt")


def resolve_policy_path(name: str) -> Path:
    """A shipped policy's file, or `name` as a path."""
    if name in SHIPPED_POLICIES:
        return Path(str(files("clamgen") / "checkpoints" / SHIPPED_POLICIES[name]))
    return Path(name)


def load_policy(name: str) -> tuple[Policy, str]:
    """A policy and a description of where it came from.

    `name`: "ik" (IK interpolation), "rrt" (OMPL RRTConnect with the full scene model),
    "base" (the shipped joint policy) or the path of a policy file from `clamgen train`.
    Raises `clamgen.experiments.checkpoint.CheckpointError` for a bad policy file.
    """
    if name == "ik":
        from clamgen.baselines import IKInterpolationPolicy

        return IKInterpolationPolicy(), "ik_interpolation"
    if name == "rrt":
        from clamgen.baselines import RRTPolicy

        return RRTPolicy(), "rrt_connect"
    from clamgen.experiments.evaluate import SACPolicy
    from clamgen.experiments.train import load_policy_agent

    path = resolve_policy_path(name)
    agent, _ = load_policy_agent(path)
    return SACPolicy(agent), str(path)


def policy_label(name: str) -> str:
    """A short name for file names: the baseline or shipped name, else the file's stem."""
    return name if name in (*BASELINES, *SHIPPED_POLICIES) else Path(name).stem
