"""Classical baselines, each a `clamgen.policy.Policy`."""

from clamgen.baselines.ik_interpolation import IKInterpolationPolicy
from clamgen.baselines.rrt import RRTConfig, RRTPolicy

__all__ = ["IKInterpolationPolicy", "RRTConfig", "RRTPolicy"]
