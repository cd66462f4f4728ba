"""Real training (minutes on a CPU): excluded from CI, run with `pytest -m slow`."""

import dataclasses

import pytest

from clamgen.experiments.config import load_preset
from clamgen.experiments.train import train


@pytest.mark.slow
def test_base_policy_learns_static_reaching(tmp_path):
    config = load_preset("base")
    loop = dataclasses.replace(
        config.loop, total_env_steps=40_000, eval_every_steps=5_000, stop_at_success=0.9
    )
    summary = train(dataclasses.replace(config, run_dir=tmp_path / "base", loop=loop), False)
    assert summary["eval/success_rate"] >= 0.9
