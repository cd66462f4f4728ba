"""`clamgen report` builds its page from small result files."""

import csv
import json

import pytest

from clamgen.experiments.report import ReportConfig, build_report
from clamgen.experiments.tables import ObstacleRow, SpeedRow


def write_results(root):
    (root / "stage1").mkdir(parents=True)
    row = SpeedRow(0.05, 4, 1.0, 1.0, 0.95, 4, 0.02, 9.0)
    (root / "stage1" / "table1_joints.json").write_text(
        json.dumps(
            {
                "policy": "base",
                "observation": "joints",
                "num_tasks": 4,
                "command": "clamgen eval",
                "rows": [row.__dict__],
            }
        )
    )
    (root / "table2").mkdir()
    for name, success in (("RRT with full model", 1.0), ("no HER (2 views)", 0.7)):
        data = ObstacleRow(name, 4, success, 0.0, success, 0.3, 0.02, 1.5).__dict__
        (root / "table2" / f"{success}.json").write_text(json.dumps({"rows": [data]}))
    for run, values in (("base", [0.1, 0.9]), ("no-her", [0.0, 0.5])):
        (root / run).mkdir()
        with (root / run / "metrics.csv").open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["step", "wall_time_s", "metric", "value"])
            for step, value in zip((1000, 2000), values, strict=True):
                writer.writerow([step, 1.0, "eval/success_rate", value])
                writer.writerow([step, 1.0, "train/critic_loss", 3.0])
    (root / "benchmarks").mkdir()
    (root / "benchmarks" / "render.csv").write_text(
        "benchmark,clamgen_per_s,pybullet_per_s,ratio\nrender_3view,400,100,4.0\n"
    )


def test_report_has_both_tables_curves_and_speed(tmp_path):
    write_results(tmp_path)
    page = build_report(ReportConfig(results_dir=tmp_path))
    text = page.read_text()
    assert "## Table 1" in text and "| 5 | 1.000 | 1.00 | 0.950 | 0.902 |" in text
    assert "## Table 2" in text
    # Rows follow the paper's order: "no HER" before "RRT".
    assert text.index("| no HER (2 views) | 0.700 (") < text.index("| RRT with full")
    assert "| 0.625 |" in text  # the paper's number beside the standard column
    assert (tmp_path / "figures" / "learning_curves.png").stat().st_size > 1000
    assert (tmp_path / "figures" / "speed.png").stat().st_size > 1000
    assert "render_3view" in text


def test_report_refuses_a_missing_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        build_report(ReportConfig(results_dir=tmp_path / "nope"))
