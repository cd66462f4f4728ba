"""`clamgen report` builds its page from small result files."""

import csv
import json

import pytest

from clamgen.experiments.aggregate import table2_row_name, write_seed_set
from clamgen.experiments.report import (
    ReportConfig,
    RunResult,
    aggregate_family,
    build_report,
    plot_family,
    row_colours,
    speed_entries,
    speed_markdown,
)
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
    (root / "benchmarks" / "act_latency.csv").write_text(
        "policy,median_ms,p95_ms,ratio_to_reference,under_aim,machine\n"
        "residual-2views,1.6,1.9,2.0,True,x86_64\n"
        "RL 2-view residual (reference),0.8,1.2,1.0,True,x86_64\n"
    )
    (root / "benchmarks" / "act_latency_noise_k0p01.csv").write_text(
        "policy,median_ms,p95_ms,ratio_to_reference,under_aim,machine\n"
        "residual-2views,2.4,2.9,3.0,False,x86_64\n"
        "RL 2-view residual (reference),0.8,1.2,1.0,True,x86_64\n"
    )


def test_report_has_both_tables_curves_and_speed(tmp_path):
    write_results(tmp_path)
    page = build_report(ReportConfig(results_dir=tmp_path, reps=100))
    text = page.read_text()
    assert "## Table 1" in text and "| 5 | 1.000 | 1.00 | 0.950 | 0.902 |" in text
    assert "## Table 2" in text
    # Rows follow the paper's order: "no HER" before "RRT".
    assert text.index("| no HER (2 views) | 0.700 (") < text.index("| RRT with full")
    assert "| 0.625 |" in text  # the paper's number beside the standard column
    # Single runs: the aggregate says so instead of inventing an interval.
    assert "| joint policy | - (not trained) | 1.000 (1 run: no interval)" in text
    assert (tmp_path / "figures" / "family_reach.png").stat().st_size > 1000
    assert (tmp_path / "figures" / "family_obstacles.png").stat().st_size > 1000
    # The speed table names the reference of every measurement.
    assert "| 3-view 128 px RGBD frames/s | 400/s | PyBullet" in text and "| 4.00x" in text
    # Acting time: the reference row is the reference, not a measurement of its own.
    assert "| 1.60 ms median, p95 1.90 ms | the RL-trained 2-view vision residual" in text
    assert "| 0.80 ms | 0.50x (reference / ours" in text
    assert text.count("act_latency.csv") == 1
    # Its noisy-depth variant is the same measurement under a stated condition.
    noisy = "acting time per step of `residual-2views` (batch 1, one core; aim < 2 ms), depth"
    assert f"{noisy} noise sd 0.01 z^2 m, shields told it | 2.40 ms median" in text
    assert "see benchmarks/act_latency_noise" not in text
    assert (tmp_path / "figures" / "speed.png").stat().st_size > 1000


def sweep_run(row, seed, table, scores, curve=((1000, 2000), (0.2, 0.6)), env=None):
    env = env or ("CLAMGen/Reach-v0" if table == 1 else "CLAMGen/ReachObstacles-v0")
    return {
        "id": f"{row}/seed{seed}",
        "row": row,
        "seed": seed,
        "status": "done",
        "train_env": env,
        "validation": {"steps": list(curve[0]), "success_rate": list(curve[1])},
        "test": {"table": table, "observation": "images", "scores": scores},
    }


def test_report_aggregates_a_sweep_over_seeds(tmp_path):
    write_results(tmp_path)
    full, ablation = "CLAMGen, 2 RGBD views", "no HER (2 views)"
    runs = [
        sweep_run(full, s, 2, {"obstacles": 0.9 + 0.01 * s, "blocked": 0.6 + 0.01 * s})
        for s in range(5)
    ]
    runs += [
        sweep_run(ablation, s, 2, {"obstacles": 0.5 + 0.01 * s, "blocked": 0.7 + 0.01 * s})
        for s in range(3)
    ]
    runs.append({**sweep_run(ablation, 9, 2, {"obstacles": 0.0}), "status": "failed"})
    summary = {
        "kind": "clamgen-sweep",
        "name": "t",
        "rows": [{"name": full}, {"name": ablation, "compare_to": full}],
        "runs": runs,
    }
    (tmp_path / "sweeps").mkdir()
    (tmp_path / "sweeps" / "summary.json").write_text(json.dumps(summary))
    text = build_report(ReportConfig(results_dir=tmp_path, reps=200)).read_text()
    # The sweep's runs replace the single-run table file of the same row; the failed run is out.
    assert f"| {full} | 5 (0, 1, 2, 3, 4) | 0.920 (" in text
    assert f"| {ablation} | 3 (0, 1, 2) | 0.510 (" in text
    assert "| 0.900, 0.910, 0.920, 0.930, 0.940 |" in text
    blocked = text[text.index("### Blocked-path tasks") :]
    assert f"| {ablation} | 3 (0, 1, 2) | 0.710 (" in blocked
    # Every full run beats every ablation run on the standard tasks, none does on blocked.
    line = next(x for x in text.splitlines() if x.startswith(f"| {ablation} | {full} |"))
    assert "| 1.00 (1.00-1.00) | holds: full CLAMGen better |" in line
    assert "| 0.00 (0.00-0.00) | fails: ablation better |" in line
    for family in ("obstacles", "blocked"):
        assert (tmp_path / "figures" / f"family_{family}.png").stat().st_size > 1000
    # Same inputs and bootstrap seed: the same page.
    again = build_report(ReportConfig(results_dir=tmp_path, reps=200)).read_text()
    assert again == text


def test_report_refuses_a_missing_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        build_report(ReportConfig(results_dir=tmp_path / "nope"))
    tmp_path.mkdir(exist_ok=True)
    with pytest.raises(FileNotFoundError, match="sweep summary not found"):
        build_report(ReportConfig(results_dir=tmp_path, sweep=(tmp_path / "none.json",)))


def test_a_run_shared_by_two_sweeps_counts_once(tmp_path):
    write_results(tmp_path)
    full, ablation = "CLAMGen, 2 RGBD views", "no HER (2 views)"
    runs = [sweep_run(full, s, 2, {"obstacles": 0.9 + 0.01 * s}) for s in range(3)]
    (tmp_path / "sweeps").mkdir()
    first = {"kind": "clamgen-sweep", "name": "a", "rows": [{"name": full}], "runs": runs}
    second = {
        "kind": "clamgen-sweep",
        "name": "b",
        "rows": [{"name": full}, {"name": ablation, "compare_to": full}],
        "runs": runs + [sweep_run(ablation, s, 2, {"obstacles": 0.5}) for s in range(2)],
    }
    (tmp_path / "sweeps" / "a.json").write_text(json.dumps(first))
    (tmp_path / "sweeps" / "b.json").write_text(json.dumps(second))
    text = build_report(ReportConfig(results_dir=tmp_path, reps=100)).read_text()
    assert f"| {full} | 3 (0, 1, 2) | 0.910 (" in text
    assert f"| {ablation} | 2 (0, 1) | 0.500 (" in text


def table2_file(path, name, obstacles, blocked):
    rows = [
        ObstacleRow(name, 4, success, 0.0, success, 0.3, 0.02, 1.5, family=family).__dict__
        for family, success in (("obstacles", obstacles), ("blocked", blocked))
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"rows": rows}))
    return path


def test_a_seed_set_makes_one_row_of_its_runs(tmp_path):
    write_results(tmp_path)
    shipped = table2_file(tmp_path / "table2" / "shipped.json", "the shipped policy", 0.9, 0.8)
    others = [
        table2_file(tmp_path / "more" / f"seed{s}.json", f"its recipe, seed {s}", 0.95, 0.6)
        for s in (7, 8)
    ]
    row = "the shipped recipe over seeds"
    out = write_seed_set(
        {row: [(5, shipped), (7, others[0]), (8, others[1])]},
        tmp_path / "more" / "seeds.json",
        "python make_seeds.py",
        "seed 5 is the shipped policy",
    )
    saved = json.loads(out.read_text())
    assert saved["kind"] == "clamgen-seeds"
    assert saved["runs"][0] == {
        "row": row,
        "seed": 5,
        "result": "../table2/shipped.json",
        "result_row": "the shipped policy",
    }
    text = build_report(ReportConfig(results_dir=tmp_path, reps=100)).read_text()
    aggregates = text[text.index("## Over training seeds") :]
    assert f"| {row} | 3 (5, 7, 8) | 0.933 (" in aggregates  # (0.9 + 0.95 + 0.95) / 3
    blocked = aggregates[aggregates.index("### Blocked-path tasks") :]
    assert f"| {row} | 3 (5, 7, 8) | 0.667 (" in blocked
    # The shipped file's row is one of the set's runs, not a row of its own; the other rows stay.
    assert "| the shipped policy |" not in aggregates
    assert "| RRT with full model | - (not trained) |" in aggregates
    assert "- `more/seeds.json` (`python make_seeds.py`): seed 5 is the shipped policy" in text


def test_a_seed_set_compares_a_wrapper_with_the_policy_alone(tmp_path):
    write_results(tmp_path)
    alone, wrapped = "policies alone", "policies through a wrapper"
    rows = {
        alone: [
            (s, table2_file(tmp_path / "s" / f"alone{s}.json", "a", 0.9, 0.5 + 0.01 * s))
            for s in (1, 2, 3)
        ],
        wrapped: [
            (s, table2_file(tmp_path / "s" / f"wrapped{s}.json", "w", 0.9, 0.9 + 0.01 * s))
            for s in (1, 2, 3)
        ],
    }
    write_seed_set(rows, tmp_path / "s" / "seeds.json", "c", "n", compare=[(wrapped, alone)])
    text = build_report(ReportConfig(results_dir=tmp_path, reps=100)).read_text()
    section = text[text.index("### What the test-time wrappers add") :]
    line = next(x for x in section.splitlines() if x.startswith(f"| {alone} | {wrapped} |"))
    # Equal on the standard tasks (every pair ties), every wrapped run ahead on blocked.
    assert "| 0.50 (0.50-0.50) | undecided |" in line
    assert "| 1.00 (1.00-1.00) | holds: the wrapper better |" in line
    with pytest.raises(ValueError, match="compare names rows not in the set"):
        write_seed_set(rows, tmp_path / "s" / "x.json", "c", "n", compare=[("nope", alone)])


def test_a_seed_set_compares_two_wrappers(tmp_path):
    write_results(tmp_path)
    names = ("through wrapper A", "through wrapper B", "alone")
    rows = {
        name: [
            (s, table2_file(tmp_path / "s" / f"{i}_{s}.json", f"r{i}", 0.9, level + 0.01 * s))
            for s in (1, 2, 3)
        ]
        for i, (name, level) in enumerate(zip(names, (0.9, 0.8, 0.5), strict=True))
    }
    a, b, alone = names
    write_seed_set(
        rows, tmp_path / "s" / "seeds.json", "c", "n", [(a, alone)], compare_wrappers=[(a, b)]
    )
    text = build_report(ReportConfig(results_dir=tmp_path, reps=100)).read_text()
    section = text[text.index("### Which test-time wrapper does better") :]
    line = next(x for x in section.splitlines() if x.startswith(f"| {b} | {a} |"))
    assert "| 0.50 (0.50-0.50) | undecided |" in line  # the standard tasks: all tie
    assert "| 1.00 (1.00-1.00) | holds: X better |" in line  # every run of A ahead of B's
    # The wrapper-against-alone table keeps its own pairs only.
    wrappers = text[text.index("### What the test-time wrappers add") : text.index(section)]
    assert f"| {alone} | {a} |" in wrappers and f"| {b} | {a} |" not in wrappers
    with pytest.raises(ValueError, match="compare_wrappers names rows not in the set"):
        write_seed_set(rows, tmp_path / "s" / "x.json", "c", "n", compare_wrappers=[(a, "z")])


def test_a_seed_set_names_a_missing_result_in_one_line(tmp_path):
    write_results(tmp_path)
    present = table2_file(tmp_path / "more" / "a.json", "a", 0.9, 0.8)
    out = write_seed_set({"r": [(0, present)]}, tmp_path / "more" / "seeds.json", "c", "n")
    present.unlink()
    with pytest.raises(FileNotFoundError, match=r"seeds\.json: result file not found: a\.json"):
        build_report(ReportConfig(results_dir=tmp_path, reps=50))
    assert out.is_file()


def test_a_seed_run_needs_a_file_of_one_row_name(tmp_path):
    path = tmp_path / "two.json"
    rows = [ObstacleRow(n, 4, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0).__dict__ for n in ("a", "b")]
    path.write_text(json.dumps({"rows": rows}))
    with pytest.raises(ValueError, match="expected one row name"):
        table2_row_name(path)


def test_mixed_task_runs_draw_their_curves_in_both_obstacle_figures(tmp_path):
    mixed, standard = "trained on the mix", "trained on standard tasks"
    results = [
        RunResult(mixed, 2, "images", {"obstacles": 0.9, "blocked": 0.7}, ([1, 2], [0.3, 0.6]),
                  seed=s, train_env="CLAMGen/ReachMixed-v0")
        for s in range(2)
    ]  # fmt: skip
    results.append(
        RunResult(standard, 2, "images", {"obstacles": 0.8, "blocked": 0.4}, ([1, 2], [0.5, 0.7]),
                  seed=0, train_env="CLAMGen/ReachObstacles-v0")
    )  # fmt: skip
    obstacles = aggregate_family(results, "obstacles", reps=50, seed=0)
    blocked = aggregate_family(results, "blocked", reps=50, seed=0)
    assert set(obstacles.curves) == {mixed, standard} and obstacles.mixed_curves == {mixed}
    # The standard run validated on standard tasks only: no curve among the blocked ones.
    assert set(blocked.curves) == {mixed} and blocked.mixed_curves == {mixed}
    plot_family(blocked, row_colours(blocked.rows), tmp_path / "blocked.png")
    assert (tmp_path / "blocked.png").stat().st_size > 1000


def test_every_row_of_a_full_table_gets_its_own_colour():
    rows = [f"row {i}" for i in range(30)]
    colours = row_colours(rows)
    assert len({tuple(c) for c in colours.values()}) == 30


def test_speed_table_names_the_reference_of_the_newer_benchmarks(tmp_path):
    (tmp_path / "concurrent_jobs.csv").write_text(
        "job,jobs_at_once,episodes_per_job,env_steps_per_job,default_s,reference_s,ratio,machine\n"
        "evaluation,2,30,,2.79,4.69,1.68,x86_64\n"
        "training,2,,1600,41.54,47.5,1.14,x86_64\n"
    )
    (tmp_path / "pool_gather.csv").write_text(
        "cache_gib,batch_rows,gathers,page_faults_ms,read_ahead_ms,ratio,machine\n"
        "1.0,128,30,235.92,10.02,23.55,x86_64\n"
    )
    (tmp_path / "first_act.csv").write_text(
        "policy,processes,page_cache_dropped,first_ms,reference_first_ms,max_ms,"
        "reference_max_ms,ratio,machine\n"
        "residual-3views,3,True,10.96,55.06,15.73,55.42,5.03,x86_64\n"
    )
    text = speed_markdown(speed_entries(tmp_path))
    assert "first act of a fresh process, `residual-3views` (page cache dropped)" in text
    assert (
        "| 11.0 ms | the same without the policy's warm-up" in text and "| 55.1 ms | 5.03x" in text
    )
    assert "| wall time of an evaluation of 30 blocked-path episodes, two at once" in text
    assert "| 2.79 s | numpy's BLAS with a thread per core" in text and "| 4.69 s | 1.68x" in text
    assert "short stage-2 training run (1600 env steps)" in text and "| 47.50 s | 1.14x" in text
    assert "| 10.0 ms | the same rows read by page faults alone" in text and "23.55x" in text
    assert "as in the file" not in text
