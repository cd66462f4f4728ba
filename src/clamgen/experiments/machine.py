"""What a result was measured on, in one line: evaluation files and benchmarks record it,
because the shipped policies' convs run in bf16 only where the CPU computes bf16 in hardware
(`clamgen.agents.encoders.native_bf16`), and act times depend on the vector instructions."""

from __future__ import annotations

import platform

import torch

from clamgen.agents.encoders import EMULATED_BF16_ENV, bf16_enabled, native_bf16


def describe() -> str:
    """E.g. "x86_64 AVX2, no bf16 in hardware" or "x86_64 AVX512, bf16 in hardware"."""
    bf16 = "bf16 in hardware" if native_bf16("cpu") else "no bf16 in hardware"
    if not native_bf16("cpu") and bf16_enabled("cpu"):
        bf16 += f" ({EMULATED_BF16_ENV}=1: emulated)"
    return f"{platform.machine()} {torch.backends.cpu.get_cpu_capability()}, {bf16}"
