"""Tables 1 and 2: well-formed rows, path ratios on the same tasks, Markdown and JSON."""

import json
import platform
import time

import numpy as np
import pytest

from clamgen.baselines import IKInterpolationPolicy
from clamgen.cli import EvalConfig, evaluate_table
from clamgen.experiments.config import TEST_SEEDS
from clamgen.experiments.evaluate import EpisodeRecord
from clamgen.experiments.tables import (
    ACT_AIM_MS,
    Z_95,
    ObstacleRow,
    PairedCount,
    paired_count,
    path_ratio,
    table1,
    table1_markdown,
    table2_markdown,
    table2_row,
    wilson_interval,
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


def test_eval_with_an_action_scale_moves_the_arm_in_more_steps(tmp_path):
    steps, paths = {}, {}
    for scale, stem in ((1.0, "full"), (0.5, "half")):
        config = EvalConfig(
            table=2,
            policy="ik",
            num_tasks=2,
            families=("obstacles",),
            action_scale=scale,
            out=tmp_path / stem,
        )
        (row,) = evaluate_table(config)
        data = json.loads((tmp_path / f"{stem}.json").read_text())
        assert data["rows"][0]["mean_steps"] == row.mean_steps
        steps[stem], paths[stem] = row.mean_steps, row.mean_tip_path_m
        assert row.reach_rate == 1.0
        # Per task, in seed order: the steps, the tip's path and collisions, in the JSON too.
        assert data["rows"][0]["task_steps"] == row.task_steps and len(row.task_steps) == 2
        assert np.mean(row.task_steps) == row.mean_steps
        assert data["rows"][0]["task_collided"] == row.task_collided
        assert len(row.task_collided) == 2 and np.mean(row.task_collided) == row.collision_rate
        assert np.mean(row.task_tip_path_m) == pytest.approx(row.mean_tip_path_m, abs=1e-5)
    assert data["policy"] == "ik_interpolation, actions scaled by 0.5"
    assert steps["half"] > 1.5 * steps["full"]  # half-length steps along the same path
    assert paths["half"] == pytest.approx(paths["full"], rel=0.05)  # ... the same path


def test_table2_with_a_moving_target_says_so(tmp_path):
    """`--target-speed` (beyond the paper): the same tasks with the target moving; the row
    records the speed and its name says it, so no paper number is set beside it."""
    rows = {}
    for speed in (0.0, 0.2):
        config = EvalConfig(
            table=2,
            policy="ik",
            num_tasks=3,
            families=("obstacles",),
            target_speed=speed,
            out=tmp_path / ("moving" if speed else "static"),
        )
        (rows[speed],) = evaluate_table(config)
    moving = rows[0.2]
    assert moving.target_speed == 0.2 and rows[0.0].target_speed == 0.0
    assert moving.name == "IK interpolation (no obstacle model), target moving at 0.2 m/s"
    saved = json.loads((tmp_path / "moving.json").read_text())["rows"][0]
    assert saved["target_speed"] == 0.2
    assert moving.task_steps != rows[0.0].task_steps  # the target moved: other episodes


def test_wilson_interval_matches_hand_computed_values():
    # 50/100: centre 0.5, half width 1.96 sqrt(0.0025 + 1.96^2 / 40000) / (1 + 1.96^2 / 100).
    low, high = wilson_interval(50, 100)
    assert low == pytest.approx(0.40383, abs=1e-5) and high == pytest.approx(0.59617, abs=1e-5)
    # 0/n and n/n: one-sided, z^2 / (n + z^2) wide, still inside [0, 1].
    assert wilson_interval(0, 200) == (0.0, pytest.approx(Z_95**2 / (200 + Z_95**2)))
    assert wilson_interval(200, 200) == (pytest.approx(200 / (200 + Z_95**2)), 1.0)
    with pytest.raises(ValueError, match="successes"):
        wilson_interval(3, 2)


def test_paired_count_counts_disagreements_and_their_sign_test():
    first = [True, True, True, False, False, True]
    second = [True, False, False, False, True, True]
    count = paired_count(first, second)
    assert (count.first_only, count.second_only) == (2, 1)
    # Three disagreements split 2:1: two-sided exact P = 2 * P(X <= 1 | n=3, p=1/2) = 1.
    assert count.p_value == pytest.approx(1.0)
    # Eight split 8:0: 2 / 2^8.
    assert paired_count([True] * 8, [False] * 8).p_value == pytest.approx(2 / 256)
    assert paired_count([True, False], [True, False]) == PairedCount(0, 0, 1.0)
    with pytest.raises(ValueError, match="one length"):
        paired_count([True], [True, False])


def obstacle_row(name, family, success, collided, reached, plan=None):
    """A row from per-task outcomes (success = reached and not collided)."""
    n = len(collided)
    success_rate = sum(r and not c for r, c in zip(reached, collided, strict=True)) / n
    assert success_rate == sum(success) / n
    return ObstacleRow(
        name,
        n,
        success_rate,
        sum(collided) / n,
        sum(reached) / n,
        0.3,
        0.1,
        plan_time_median_s=plan,
        plan_time_p95_s=plan,
        task_success=success,
        family=family,
    )


def test_failure_split_counts_each_kind_of_failure_once():
    # 6 tasks: 2 successes, 1 collided and never reached, 2 stalled, 1 reached after a collision.
    reached = [True, True, False, False, False, True]
    collided = [False, False, True, False, False, True]
    success = [True, True, False, False, False, False]
    row = obstacle_row("r", "blocked", success, collided, reached)
    assert row.num_successes == 2
    assert row.failure_split == {
        "collided_never_reached": 1,
        "stalled_no_collision": 2,
        "reached_after_collision": 1,
    }


def test_table2_markdown_puts_both_families_side_by_side_with_intervals():
    ik_std = obstacle_row(
        "IK interpolation (no obstacle model)",
        "obstacles",
        [True] * 3 + [False],
        [False] * 3 + [True],
        [True] * 3 + [False],
    )
    ik_blk = obstacle_row(
        "IK interpolation (no obstacle model)", "blocked", [False] * 4, [True] * 4, [False] * 4
    )
    rrt_std = obstacle_row(
        "RRT with full model", "obstacles", [True] * 4, [False] * 4, [True] * 4, 0.05
    )
    old = ObstacleRow("no HER (2 views)", 4, 0.5, 0.25, 0.75, 0.3, 0.1)  # written before families
    lines = table2_markdown([ik_std, ik_blk, rrt_std, old]).splitlines()
    assert "standard: success (95% CI, n=4)" in lines[0] and "blocked: success" in lines[0]
    assert len(lines) == 5  # header, rule, one line per row name
    low, high = wilson_interval(3, 4)
    assert lines[2].startswith(
        f"| IK interpolation (no obstacle model) | 0.750 ({low:.3f}-{high:.3f}) | - "
        f"| 0.000 (0.000-{wilson_interval(0, 4)[1]:.3f}) | 0.250 / 1.000 | 1 / 0 / 0 | 4 / 0 / 0 |"
    )
    assert "| RRT with full model | 1.000 (" in lines[3] and "| 1.0 | - |" in lines[3]
    assert lines[3].endswith("| 0.050 / 0.050 / - |")
    # An old row: the split from its rates (1 reached after a collision, 0 collided only).
    assert "| no HER (2 views) | 0.500 (" in lines[4] and "| 0.625 | - |" in lines[4]
    assert "| 0 / 1 / 1 | - |" in lines[4]
    assert "n=21" not in "\n".join(lines)


def test_table2_command_runs_both_families_on_test_seeds(tmp_path, capsys):
    rows = evaluate_table(
        EvalConfig(table=2, policy="ik", num_tasks=3, out=tmp_path / "ik", speeds=("0",))
    )
    printed = capsys.readouterr().out
    assert printed.count(f"of acts over {ACT_AIM_MS:g} ms") == 2  # the act tail, per family
    assert [row.family for row in rows] == ["obstacles", "blocked"]
    assert all(row.first_seed == TEST_SEEDS.start and row.num_tasks == 3 for row in rows)
    assert rows[1].success_rate == 0.0 and rows[1].collision_rate == 1.0  # blind path blocked
    data = json.loads((tmp_path / "ik.json").read_text())
    assert [row["family"] for row in data["rows"]] == ["obstacles", "blocked"]
    assert data["machine"].startswith(platform.machine())  # the CPU it ran on, and its bf16
    assert "bf16 in hardware" in data["machine"]
    loaded = [ObstacleRow(**row) for row in data["rows"]]
    assert (tmp_path / "ik.md").read_text() == table2_markdown(loaded) + "\n"
    with pytest.raises(SystemExit, match="families"):
        evaluate_table(EvalConfig(table=2, policy="ik", num_tasks=1, families=("hard",)))


class _SlowEveryOtherAct:
    """Stands still, sleeping past the act aim on every other act."""

    def __init__(self) -> None:
        self.acts = 0

    def reset(self, env=None) -> None:
        pass

    def act(self, obs):
        self.acts += 1
        if self.acts % 2:
            time.sleep(2 * ACT_AIM_MS / 1e3)
        return np.zeros(6, np.float32)


def test_table2_rows_record_the_share_of_acts_over_the_aim():
    slow = _SlowEveryOtherAct()
    row = table2_row("slow", slow, num_tasks=2, family="obstacles")
    # Every other act sleeps twice the aim; the others return at once.
    assert slow.acts == 200  # two episodes to the time limit
    assert row.act_share_over_aim == pytest.approx(0.5, abs=0.05)
    assert row.act_max_ms > 2 * ACT_AIM_MS
