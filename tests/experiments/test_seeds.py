"""Seed ranges: disjoint, training never on test seeds, periodic evaluation on validation
seeds, tables on test seeds only."""

import itertools

import numpy as np
import pytest

from clamgen.cli import EvalConfig, evaluate_table
from clamgen.experiments import train as train_module
from clamgen.experiments.config import (
    MAX_TRAINING_LOOP_SEED,
    SEED_RANGES,
    TEST_SEEDS,
    TRAINING_ENV_SEED_STRIDE,
    TRAINING_SEEDS,
    VALIDATION_SEEDS,
    LoopConfig,
    check_table_seeds,
)


def test_ranges_are_disjoint_and_the_test_range_keeps_the_committed_tables_seeds():
    spans = sorted((r.start, r.stop) for r in SEED_RANGES)
    assert all(stop <= start for (_, stop), (start, _) in itertools.pairwise(spans))
    # results/table* were made on seeds 1000000000 + i: they stay test seeds.
    assert TEST_SEEDS.start == 1_000_000_000 and 1_000_000_199 in TEST_SEEDS
    assert EvalConfig().first_seed == TEST_SEEDS.start
    for seed in (0, TRAINING_SEEDS.stop - 1):
        assert seed in TRAINING_SEEDS and seed not in VALIDATION_SEEDS and seed not in TEST_SEEDS
    assert VALIDATION_SEEDS.start not in TEST_SEEDS and VALIDATION_SEEDS.start not in TRAINING_SEEDS


def test_seeds_come_from_their_range_or_fail():
    np.testing.assert_array_equal(VALIDATION_SEEDS.seeds(3), VALIDATION_SEEDS.start + np.arange(3))
    with pytest.raises(ValueError, match="validation seed"):
        check_table_seeds(VALIDATION_SEEDS.start + 5, 10)
    with pytest.raises(ValueError, match="not all test seeds"):
        check_table_seeds(TEST_SEEDS.stop - 5, 10)  # runs off the end of the range
    assert len(check_table_seeds(TEST_SEEDS.start, 200)) == 200


def test_training_refuses_loop_seeds_whose_env_seeds_leave_the_training_range():
    LoopConfig(seed=0)
    LoopConfig(seed=MAX_TRAINING_LOOP_SEED)
    assert (MAX_TRAINING_LOOP_SEED + 1) * TRAINING_ENV_SEED_STRIDE >= TRAINING_SEEDS.stop
    with pytest.raises(ValueError, match="is a test seed"):
        LoopConfig(seed=TEST_SEEDS.start)
    with pytest.raises(ValueError, match="is a validation seed"):
        LoopConfig(seed=VALIDATION_SEEDS.start)
    for seed in (-1, MAX_TRAINING_LOOP_SEED + 1):
        with pytest.raises(ValueError, match=r"loop\.seed must be in"):
            LoopConfig(seed=seed)


def test_periodic_evaluation_runs_on_validation_seeds(tmp_path, monkeypatch):
    from test_train import tiny_config

    seen = []
    original = train_module.evaluate

    def fake_evaluate(env, policy, seeds):
        seen.extend(int(s) for s in seeds)
        return original(env, policy, seeds[:1])

    trainer = train_module.Trainer(tiny_config(tmp_path / "run", num_eval_episodes=4))
    monkeypatch.setattr(train_module, "evaluate", fake_evaluate)
    summary = trainer.evaluate()
    assert seen == list(VALIDATION_SEEDS.start + np.arange(4))
    assert 0 <= summary["eval/success_rate"] <= 1


@pytest.mark.parametrize("table", [1, 2])
def test_table_commands_refuse_validation_seeds(table, tmp_path):
    config = EvalConfig(
        table=table, policy="ik", num_tasks=2, first_seed=VALIDATION_SEEDS.start, out=tmp_path / "t"
    )
    with pytest.raises(SystemExit, match="validation seed"):
        evaluate_table(config)
    assert not (tmp_path / "t.json").exists()
