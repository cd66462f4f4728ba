"""Typed schedules of training progress (never parsed from strings)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LinearRamp:
    """`start_value` until `start_fraction` of training, linear to `end_value` at `end_fraction`,
    then constant. The paper's collision-penalty curriculum is LinearRamp(0.3, 0.9, 0.0, 0.1)."""

    start_fraction: float = 0.3
    """Fraction of training at which the ramp starts."""
    end_fraction: float = 0.9
    """Fraction of training at which the ramp reaches `end_value`."""
    start_value: float = 0.0
    """Value before the ramp."""
    end_value: float = 0.1
    """Value after the ramp."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.start_fraction <= self.end_fraction <= 1.0:
            raise ValueError(
                "need 0 <= start_fraction <= end_fraction <= 1, got "
                f"{self.start_fraction}, {self.end_fraction}"
            )

    def __call__(self, progress: float) -> float:
        """Value at `progress` in [0, 1] (fraction of the training budget done)."""
        if progress <= self.start_fraction:
            return self.start_value
        if progress >= self.end_fraction:
            return self.end_value
        t = (progress - self.start_fraction) / (self.end_fraction - self.start_fraction)
        return self.start_value + t * (self.end_value - self.start_value)


@dataclass(frozen=True)
class Constant:
    """The same value throughout training."""

    value: float = 0.0
    """The value."""

    def __call__(self, progress: float) -> float:
        return self.value


Schedule = LinearRamp | Constant
