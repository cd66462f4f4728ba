"""What a result was measured on, in one line: evaluation files and benchmarks record it,
because the shipped policies' convs run in bf16 only where the CPU computes bf16 in hardware
(`clamgen.agents.encoders.native_bf16`), and act times depend on the vector instructions, on
the unit that computes bf16 (AMX tiles or AVX-512 BF16) and on the CPU model
(`results/benchmarks/act_latency_runs/`)."""

from __future__ import annotations

import platform
from pathlib import Path

import torch

from clamgen.agents.encoders import EMULATED_BF16_ENV, bf16_enabled, cpu_bf16_unit, native_bf16

CPUINFO = Path("/proc/cpuinfo")
"""Where Linux names the CPU model (elsewhere the description leaves it out)."""


def cpu_model(cpuinfo: Path = CPUINFO) -> str:
    """The CPU's model name as Linux reports it (e.g. "AMD EPYC"), or "" where unknown."""
    try:
        text = cpuinfo.read_text()
    except OSError:
        return ""
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "model name":
            return " ".join(value.split())
    return ""


def describe(cpuinfo: Path = CPUINFO) -> str:
    """E.g. "x86_64 AVX2, no bf16 in hardware" or "x86_64 AVX512, bf16 in hardware (AVX-512
    BF16, no AMX), AMD EPYC"; the model name where Linux gives one."""
    if native_bf16("cpu"):
        unit = cpu_bf16_unit()
        bf16 = f"bf16 in hardware ({unit})" if unit else "bf16 in hardware"
    else:
        bf16 = "no bf16 in hardware"
        if bf16_enabled("cpu"):
            bf16 += f" ({EMULATED_BF16_ENV}=1: emulated)"
    model = cpu_model(cpuinfo)
    text = f"{platform.machine()} {torch.backends.cpu.get_cpu_capability()}, {bf16}"
    return f"{text}, {model}" if model else text
