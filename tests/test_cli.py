"""The `clamgen` command line: typed choices in `--help`, presets, policy-following defaults."""

import json

import imageio.v3 as iio
import pytest

from clamgen import cli
from clamgen.experiments.policies import BASELINES, SHIPPED_POLICIES, PolicyName


@pytest.fixture(autouse=True)
def wide_terminal(monkeypatch):
    # tyro wraps help to the terminal's width (and splits it into columns when very wide):
    # one column, wide enough that no choice list is split.
    monkeypatch.setenv("COLUMNS", "120")


POLICY_CHOICES = (
    "--policy {base,residual-3views,residual-2views,residual-1view,image-only,ik,rrt,"
    "depth-rrt-3views,depth-rrt-2views,depth-rrt-1view}|PATH"
)


def unwrapped(text: str) -> str:
    """Help text with its box's wrapped lines joined (a choice list may span two)."""
    return "".join(line.strip(" │") for line in text.splitlines())


def help_text(capsys, *argv: str) -> str:
    with pytest.raises(SystemExit) as exit_info:
        cli.main([*argv, "--help"])
    assert exit_info.value.code in (None, 0)
    return capsys.readouterr().out


def test_policy_choices_are_the_shipped_policies_and_baselines():
    assert PolicyName.__args__ == (*SHIPPED_POLICIES, *BASELINES)


def test_usage_lists_commands_presets_and_policies(capsys):
    cli.main([])
    text = capsys.readouterr().out
    for name in cli.COMMANDS:
        assert f"  {name}" in text
    assert "residual-cpu" in text and "image-only-cpu" in text
    shipped = "residual-3views, residual-2views, residual-1view, image-only"
    assert f"{shipped}; baselines: ik, rrt" in text


def test_eval_help_lists_tables_and_every_policy(capsys):
    text = help_text(capsys, "eval")
    assert "--table {1,2}" in text
    assert POLICY_CHOICES in unwrapped(text)


def test_train_help_lists_presets_and_choices(capsys):
    text = help_text(capsys, "train")
    assert "--preset {" + ",".join(cli.PRESET_NAMES) + "}|PATH" in text
    assert {"base", "residual-cpu", "image-only-cpu"} <= set(cli.PRESET_NAMES)
    assert "--env.obs-mode {joints,images,both}" in text
    text = help_text(capsys, "train-residual")
    assert "--agent.obs-source {images,obstacles}" in text
    assert "(default: residual-cpu)" in text
    # The defaults shown are the preset's.
    assert "runs/base" in help_text(capsys, "train")
    assert "runs/residual-obstacles" in help_text(
        capsys, "train-residual", "--preset", "residual-obstacles"
    )


def test_render_help_lists_policies(capsys):
    text = help_text(capsys, "render")
    assert POLICY_CHOICES in unwrapped(text)


def test_preset_sets_defaults_and_the_command_line_overrides_them():
    config = cli._train_config(["--preset", "residual-cpu", "--loop.seed", "3"], stage=2)
    assert config.env.num_views == 2 and config.env.image_size == 64 and config.loop.seed == 3
    config = cli._train_config(["--preset=base", "--env.obs-mode", "joints"])
    assert config.env.obs_mode == "joints"
    assert config.run_dir.name == "base"


def test_bad_choices_are_refused(capsys):
    with pytest.raises(SystemExit, match="no preset 'nope'; known presets"):
        cli._train_config(["--preset", "nope"])
    with pytest.raises(SystemExit, match="--preset needs a value"):
        cli._train_config(["--preset"])
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["eval", "--table", "3"])
    assert exit_info.value.code == 2
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["train", "--env.obs-mode", "pixels"])
    assert exit_info.value.code == 2


def test_render_views_follow_the_policy():
    assert cli._render_config(["--policy", "residual-2views"]).num_views == 2
    assert cli._render_config(["--policy", "ik"]).num_views == 3
    assert cli._render_config(["--policy", "residual-2views", "--num-views", "1"]).num_views == 1


def test_render_of_a_two_view_policy_draws_two_cameras(tmp_path):
    out = tmp_path / "rollout"
    cli.main(["render", "--policy", "residual-2views", "--num-episodes", "1", "--out", str(out)])
    frame = iio.imread(out.with_suffix(".mp4"), index=0)
    # The 640 px outside view, then one column of views each 480 / 2 px wide (3 views: 160).
    assert frame.shape == (480, 640 + 240, 3)
    assert json.loads(out.with_suffix(".json").read_text())["policy"] == "residual-2views"


def test_report_from_another_directory(tmp_path, monkeypatch, capsys):
    results = tmp_path / "my_results"
    (results / "benchmarks").mkdir(parents=True)
    (results / "benchmarks" / "render.csv").write_text(
        "benchmark,clamgen_per_s,pybullet_per_s,ratio\nrender_3view,400,100,4.0\n"
    )
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    with pytest.raises(SystemExit, match=r"results directory not found: .*pass --results DIR"):
        cli.main(["report"])
    cli.main(["report", "--results", "../my_results"])
    assert "wrote ../my_results/REPORT.md" in capsys.readouterr().out
    assert "render.csv" in (results / "REPORT.md").read_text()  # the speed table cites it
    assert (results / "figures" / "speed.png").exists()
