"""The one-line machine description that evaluations and benchmarks record."""

from __future__ import annotations

import platform

import torch

from clamgen.agents.encoders import cpu_bf16_unit, native_bf16
from clamgen.experiments import machine

CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
model name\t: AMD EPYC  9R14
flags\t\t: fpu avx2

processor\t: 1
model name\t: AMD EPYC  9R14
"""


def test_cpu_model_is_read_from_cpuinfo_with_its_spaces_collapsed(tmp_path):
    path = tmp_path / "cpuinfo"
    path.write_text(CPUINFO)
    assert machine.cpu_model(path) == "AMD EPYC 9R14"
    path.write_text("processor\t: 0\nflags\t: fpu\n")
    assert machine.cpu_model(path) == ""
    assert machine.cpu_model(tmp_path / "missing") == ""


def test_describe_names_the_architecture_bf16_unit_and_model(tmp_path):
    path = tmp_path / "cpuinfo"
    path.write_text(CPUINFO)
    text = machine.describe(path)
    assert text.startswith(f"{platform.machine()} {torch.backends.cpu.get_cpu_capability()}, ")
    assert text.endswith(", AMD EPYC 9R14")
    if native_bf16("cpu"):
        assert f"bf16 in hardware ({cpu_bf16_unit()})" in text
        assert cpu_bf16_unit() in ("AMX", "AVX-512 BF16, no AMX")
    else:
        assert "no bf16 in hardware" in text and cpu_bf16_unit() == ""
    # Without a model name (not Linux), the description ends with the bf16 part.
    assert machine.describe(tmp_path / "missing") == text.removesuffix(", AMD EPYC 9R14")
