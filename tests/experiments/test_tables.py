"""Tables 1 and 2: well-formed rows, path ratios on the same tasks, Markdown and JSON."""

import json

import numpy as np
import pytest

from clamgen.baselines import IKInterpolationPolicy
from clamgen.cli import EvalConfig, evaluate_table
from clamgen.experiments.evaluate import EpisodeRecord
from clamgen.experiments.tables import (
    ObstacleRow,
    blocked_success,
    blocked_tasks,
    path_ratio,
    table1,
    table1_markdown,
    table2_markdown,
    write_table1,
)


def record(success, path, collided=False):
    return EpisodeRecord(seed=0, reached=success, collided=collided, steps=5, tip_path_m=path)


def test_path_ratio_uses_tasks_both_solved():
    policy = [record(True, 0.9), record(True, 2.0), record(False, 1.0), record(True, 1.0, True)]
    baseline = [record(True, 1.0), record(False, 1.0), record(True, 1.0), record(True, 1.0)]
    assert path_ratio(policy, baseline) == (pytest.approx(0.9), 1)


def test_ik_baseline_against_itself_gives_ratio_one(tmp_path):
    rows = table1(IKInterpolationPolicy(), num_tasks=3, speeds=(0.0, "variable"))
    assert [row.speed for row in rows] == [0.0, "variable"]
    for row in rows:
        assert row.success_rate == row.baseline_success_rate == 1.0
        assert row.path_ratio == pytest.approx(1.0)
        assert row.median_act_ms > 0
    write_table1(rows, tmp_path / "t1", {"policy": "ik", "observation": "joints"})
    data = json.loads((tmp_path / "t1.json").read_text())
    assert len(data["rows"]) == 2 and data["policy"] == "ik"
    markdown = (tmp_path / "t1.md").read_text()
    assert markdown.count("\n") == 4 and "variable [5-20]" in markdown
    assert "| 0.905 |" in table1_markdown(rows)  # the paper's variable-speed ratio 0.9048


def test_eval_command_on_a_trained_policy_file(tmp_path):
    from test_train import tiny_config

    from clamgen.experiments.train import POLICY_NAME, Trainer

    config = tiny_config(tmp_path / "run", total=80)
    Trainer(config).run(show_progress=False)
    rows = evaluate_table(
        EvalConfig(
            policy=str(config.run_dir / POLICY_NAME),
            num_tasks=2,
            speeds=("0", "0.2"),
            out=tmp_path / "t1",
        )
    )
    assert [row.speed for row in rows] == [0.0, 0.2]
    assert all(0 <= row.success_rate <= 1 and row.median_act_ms > 0 for row in rows)
    data = json.loads((tmp_path / "t1.json").read_text())
    assert data["policy"].endswith(POLICY_NAME) and data["num_tasks"] == 2


def test_eval_command_errors_are_clear(tmp_path):
    with pytest.raises(SystemExit, match="not found"):
        evaluate_table(EvalConfig(policy=str(tmp_path / "missing.pt"), num_tasks=1))
    with pytest.raises(SystemExit, match="speeds"):
        evaluate_table(EvalConfig(policy="ik", num_tasks=1, speeds=("fast",)))
    rows = evaluate_table(
        EvalConfig(policy="ik", num_tasks=2, speeds=("0.1",), out=tmp_path / "ik")
    )
    assert len(rows) == 1 and np.isfinite(rows[0].path_ratio)
    assert (tmp_path / "ik.md").exists()


def test_table2_blocked_column_scores_rows_on_the_tasks_ik_interpolation_failed():
    def row(name, success):
        rate = sum(success) / len(success)
        return ObstacleRow(name, len(success), rate, 0.0, rate, 0.3, 0.1, task_success=success)

    rows = [
        row("IK interpolation (no obstacle model)", [True, False, True, False]),
        row("CLAMGen, 2 RGBD views", [True, True, False, False]),
        ObstacleRow("old row", 4, 0.5, 0.0, 0.5, 0.3, 0.1),  # written before per-task results
    ]
    blocked = blocked_tasks(rows)
    np.testing.assert_array_equal(blocked, [False, True, False, True])
    assert blocked_success(rows[1], blocked) == 0.5 and blocked_success(rows[2], blocked) is None
    lines = table2_markdown(rows).splitlines()
    assert "success on blocked tasks (n=2)" in lines[0]
    assert "| CLAMGen, 2 RGBD views | 0.500 | 0.76 | 0.500 |" in lines[3]
    assert "| old row | 0.500 | - | - |" in lines[4]
    assert "blocked" not in table2_markdown(rows[1:])  # no IK row: no column
