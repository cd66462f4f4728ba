"""Classical baselines, each a `clamgen.policy.Policy`."""

from clamgen.baselines.ik_interpolation import IKInterpolationPolicy

__all__ = ["IKInterpolationPolicy"]
