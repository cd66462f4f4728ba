"""Bad input is refused at the boundary in one line that names the field, the value and what is
allowed; the `clamgen` commands exit non-zero with that line (the traceback behind `--debug`)
and leave the disk as it was."""

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from clamgen import cli
from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import load_preset
from clamgen.experiments.policies import policy_label
from clamgen.experiments.video import RenderConfig, output_stem
from clamgen.sim.scene import Obstacles
from clamgen.tasks.reach import Task

# A stage-1 run small enough that, were the bad input accepted, it would finish in seconds.
TINY_TRAIN = (
    "--env.num-envs",
    "1",
    "--replay.capacity",
    "1000",
    "--loop.total-env-steps",
    "8",
    "--loop.learning-starts",
    "4",
    "--loop.eval-every-steps",
    "0",
    "--loop.num-eval-episodes",
    "1",
)


def snapshot(root: Path) -> dict[str, tuple[int, str]]:
    """Every path under `root`: its size and content hash (directories: -1, '')."""
    state = {}
    for path in sorted(root.rglob("*")):
        if path.is_file():
            state[str(path.relative_to(root))] = (
                path.stat().st_size,
                hashlib.sha256(path.read_bytes()).hexdigest(),
            )
        else:
            state[str(path.relative_to(root))] = (-1, "")
    return state


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """An empty working directory, so that default outputs (runs/...) would land in it."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def refused(workdir: Path, *argv: str) -> str:
    """Run `clamgen ARGV` in-process; assert it exits with a one-line message (exit status 1)
    and changes nothing under `workdir`; return the message."""
    before = snapshot(workdir)
    with pytest.raises(SystemExit) as exit_info:
        cli.main(list(argv))
    message = exit_info.value.code
    # A string code is printed to stderr and the process exits with status 1.
    assert isinstance(message, str), f"exit code {message!r}, expected a message"
    assert "\n" not in message.strip() and "Traceback" not in message
    assert message.startswith(f"clamgen {argv[0]}: ")
    assert snapshot(workdir) == before, "the refused command changed files on disk"
    return message


# ------------------------------------------------------------------ train: bad values
@pytest.mark.parametrize(
    ("flags", "expected"),
    [
        (
            ("--loop.updates-per-step", "nan"),
            "loop.updates_per_step must be a finite number >= 0, got nan",
        ),
        (("--agent.gamma", "2"), "agent.gamma must be in [0, 1], got 2"),
        (("--agent.critic-lr", "0"), "agent.critic_lr must be a finite number > 0, got 0"),
        (("--agent.actor-lr", "-1"), "agent.actor_lr must be a finite number > 0, got -1"),
        (("--agent.batch-size", "0"), "agent.batch_size must be an integer >= 1, got 0"),
        (("--agent.tau", "0"), "agent.tau must be in (0, 1], got 0"),
        (("--env.image-size", "10000"), "env.image_size must be an integer in 8..1024, got 10000"),
        (("--env.num-views", "5"), "env.num_views must be an integer in 0..4, got 5"),
        (
            ("--env.num-views", "2"),
            "env.num_views=2 does not fit env.obs_mode='joints': views need obs_mode 'images' "
            "or 'both'",
        ),
        (("--env.target-speed", "zzz"), "env.target_speed: target speed must be a number"),
        (("--loop.stop-at-success", "2"), "loop.stop_at_success must be in [0, 1] or None"),
    ],
)
def test_train_refuses_bad_values(workdir, flags, expected):
    message = refused(workdir, "train", "--run-dir", "run", *TINY_TRAIN, *flags)
    assert expected in message


def test_stage2_refuses_bad_agent_values(workdir):
    message = refused(workdir, "train-residual", "--run-dir", "run", "--agent.gamma", "1.5")
    assert "agent.gamma must be in [0, 1], got 1.5" in message


# ------------------------------------------------------------------ train: bad presets
@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('[loop]\ntotal_env_steps = "abc"\n', "loop.total_env_steps = 'abc': expected an integer"),
        (
            "[agent]\nhidden_sizes = 256\n",
            "agent.hidden_sizes = 256: expected a list of integers",
        ),
        ("[env]\nnum_envs = 2.5\n", "env.num_envs = 2.5: expected an integer"),
        ('[agent]\nbatch_size = "64"\n', "agent.batch_size = '64': expected an integer"),
        ("[env]\nobs_mode = 3\n", "env.obs_mode = 3: expected one of 'joints', 'images', 'both'"),
        ("[loop]\nupdates_per_step = nan\n", "loop.updates_per_step must be a finite number"),
        ("[agent]\ngamma = 2.0\n", "agent.gamma must be in [0, 1], got 2.0"),
        ("[agent]\nbatch_sizes = 64\n", "unknown SACConfig fields ['batch_sizes'] in agent"),
        ("[loop\nseed = 1\n", "TOML syntax error: Expected ']'"),
    ],
)
def test_train_refuses_bad_presets_naming_the_file(workdir, text, expected):
    preset = workdir / "bad.toml"
    preset.write_text(text)
    message = refused(workdir, "train", "--preset", str(preset), "--run-dir", "run")
    assert f"preset {preset}: " in message
    assert expected in message


def test_shipped_presets_pass_the_type_checks():
    from clamgen.experiments.config import TrainConfig
    from clamgen.experiments.stage2 import Stage2Config

    for name in cli.PRESET_NAMES:
        config = load_preset(name, TrainConfig if name == "base" else Stage2Config)
        assert isinstance(config.loop.total_env_steps, int)


# ------------------------------------------------------------- train: the run directory
def test_train_refuses_a_run_dir_that_is_a_file(workdir):
    (workdir / "run").write_text("not a directory")
    message = refused(workdir, "train", "--run-dir", "run", *TINY_TRAIN)
    assert "--run-dir run is a file, not a directory" in message
    message = refused(workdir, "train", "--run-dir", "run/sub", *TINY_TRAIN)
    assert "--run-dir run/sub cannot be created: run is a file" in message


def test_train_refuses_a_run_dir_it_cannot_write(workdir):
    # Root writes through permission bits; /proc/1 cannot be written even by root.
    if os.geteuid() == 0:
        target = Path("/proc/1/clamgen-run")
        if not Path("/proc/1").is_dir():
            pytest.skip("needs /proc when running as root")
        message = refused(workdir, "train", "--run-dir", str(target), *TINY_TRAIN)
        assert f"--run-dir {target} cannot be created: /proc/1 is not writable" in message
        return
    locked = workdir / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        message = refused(workdir, "train", "--run-dir", "locked/run", *TINY_TRAIN)
        assert "cannot be created: locked is not writable" in message
    finally:
        locked.chmod(0o755)


def test_train_refuses_a_replay_that_does_not_fit(workdir):
    message = refused(
        workdir, "train", "--run-dir", "run", *TINY_TRAIN, "--replay.capacity", str(10**12)
    )
    assert "at peak (replay capacity 1000000000000" in message
    assert "lower replay.capacity" in message


def test_train_refuses_a_damaged_checkpoint(workdir):
    damaged = workdir / "run" / "checkpoints" / f"{ckpt.CHECKPOINT_PREFIX}000001"
    damaged.mkdir(parents=True)
    (damaged / "manifest.json").write_text("{ not json")
    message = refused(workdir, "train", "--run-dir", "run", *TINY_TRAIN)
    assert "no intact checkpoint in run/checkpoints" in message
    assert "ckpt-000001 is damaged" in message


@pytest.mark.parametrize(
    ("base", "expected"),
    [
        ("nosuch.pt", "--base-policy 'nosuch.pt': no such policy file; pass `base` (shipped)"),
        ("residual-2views", "not a stage-1 policy ('sac-policy')"),
    ],
)
def test_train_residual_refuses_a_wrong_base_policy(workdir, base, expected):
    if base in ckpt.SHIPPED_POLICIES:  # a stage-2 policy file where a stage-1 one belongs
        shutil.copy(ckpt.resolve_policy_path(base), workdir / "residual.pt")
        base = "residual.pt"
    message = refused(workdir, "train-residual", "--run-dir", "run", "--base-policy", base)
    assert expected in message


# ------------------------------------------------------------------- eval and render
def test_eval_render_and_view_list_the_valid_policies(workdir):
    for command in ("eval", "render", "view"):
        message = refused(workdir, command, "--policy", "nosuch")
        assert (
            "--policy 'nosuch' not found; choose one of base, residual-3views, "
            "residual-2views, residual-1view, " in message
        )
        assert (
            "image-only, ik, rrt, depth-rrt-3views, depth-rrt-2views, depth-rrt-1view, or the "
            "path of a policy file" in message
        )
    (workdir / "run").mkdir()
    message = refused(workdir, "eval", "--policy", "run")
    assert "run is a directory; its policy file is run/policy.pt" in message


def test_eval_target_speed_is_table2s_and_not_negative(workdir):
    message = refused(workdir, "eval", "--policy", "ik", "--target-speed", "0.1")
    assert "--target-speed is Table 2's (Table 1 takes --speeds)" in message
    message = refused(workdir, "eval", "--table", "2", "--policy", "ik", "--target-speed", "-1")
    assert "bad --target-speed: target speed must be finite and >= 0 m/s, got -1.0" in message
    assert "--real-time is Table 2's" in refused(workdir, "eval", "--policy", "ik", "--real-time")


def test_eval_depth_noise_is_table2s_and_needs_views(workdir):
    noise = ("--depth-noise-m", "0.01")
    assert "--depth-noise-m is Table 2's" in refused(workdir, "eval", "--policy", "ik", *noise)
    message = refused(workdir, "eval", "--table", "2", "--policy", "ik", "--depth-noise-m", "-1")
    assert "--depth-noise-m must be a number >= 0, got -1.0" in message
    message = refused(workdir, "eval", "--table", "2", "--policy", "ik", "--num-tasks", "1", *noise)
    assert "--depth-noise-m perturbs the views' depth: this policy observes none" in message


def test_eval_and_render_refuse_an_output_stem_whose_dot_would_be_a_suffix(workdir):
    """`--out run-0.1` would write run-0.json (the files' suffixes replace '.1')."""
    for command in ("eval", "render"):
        message = refused(workdir, command, "--policy", "ik", "--out", "run-0.1")
        assert "its '.1' would be read as a file suffix and replaced" in message
        assert "(e.g. run-0p1)" in message
    assert not list(workdir.glob("run-0*"))


def test_eval_lookahead_needs_a_privileged_residual(workdir):
    message = refused(workdir, "eval", "--policy", "base", "--lookahead-candidates", "4")
    assert "--lookahead-candidates needs a privileged residual" in message
    message = refused(workdir, "eval", "--policy", "base", "--lookahead-candidates", "-1")
    assert "--lookahead-candidates must be >= 0, got -1" in message
    message = refused(
        workdir,
        "eval",
        "--policy",
        "base",
        "--lookahead-candidates",
        "4",
        "--lookahead-margin-m",
        "-0.01",
    )
    assert "--lookahead-margin-m must be a number >= 0, got -0.01" in message


def test_eval_action_scale_outside_0_1_is_one_line(workdir):
    for scale in ("0", "1.5", "nan"):
        message = refused(
            workdir, "eval", "--table", "2", "--policy", "ik", "--action-scale", scale
        )
        assert f"bad --action-scale: action scale must be in (0, 1], got {float(scale)}" in message


def test_eval_depth_shield_needs_a_vision_residual_and_a_margin(workdir):
    message = refused(
        workdir, "eval", "--table", "2", "--policy", "base", "--depth-shield-m", "0.01"
    )
    assert "the depth shield needs a vision residual" in message
    assert "or --depth-views V for a policy that sees no images" in message
    for policy, views, extra, expected in (
        ("base", "2", [], "--depth-views renders views for the depth wrapper: give its options"),
        ("base", "5", ["--depth-hybrid"], "--depth-views must be in 0..4, got 5"),
        ("base", "-1", ["--depth-escapes"], "--depth-views must be in 0..4, got -1"),
        (
            "residual-1view",
            "3",
            ["--depth-hybrid"],
            "--depth-views 3: this policy acts on its own 1 view(s), which the depth wrapper "
            "reads; drop --depth-views",
        ),
    ):
        args = ["--table", "2", "--policy", policy, "--depth-views", views, *extra]
        assert expected in refused(workdir, "eval", *args)
    margin = ("--depth-shield-m", "0.01")
    for args, expected in (
        (
            ("--depth-shield-m", "-1"),
            "bad --depth-shield-m: margin_m must be a number >= 0, got -1.0",
        ),
        (("--depth-planner",), "--depth-planner needs --depth-shield-m"),
        (("--depth-shadow-m", "0.07"), "--depth-shadow-m needs --depth-shield-m"),
        ((*margin, "--depth-shadow-m", "0"), "--depth-shadow-m must be a number > 0, got 0.0"),
        (
            (*margin, "--depth-shadow-behind-surfaces"),
            "--depth-shadow-behind-surfaces needs --depth-shadow-m",
        ),
        (("--depth-bridge-m", "0.05"), "--depth-bridge-m needs --depth-shield-m"),
        (
            (*margin, "--depth-bridge-m", "-0.05"),
            "--depth-bridge-m must be a number >= 0, got -0.05",
        ),
        (
            ("--depth-hybrid", "--depth-shield-m", "0.02"),
            "--depth-hybrid sets the depth options itself: drop the others",
        ),
        (("--depth-fine-size", "128"), "--depth-fine-size needs --depth-shield-m"),
        ((*margin, "--depth-fine-size", "4"), "--depth-fine-size must be 0 or 8..1024, got 4"),
        ((*margin, "--depth-plan-checks", "5000"), "--depth-plan-checks needs --depth-planner"),
    ):
        assert expected in refused(
            workdir, "eval", "--table", "2", "--policy", "residual-1view", *args
        )
    message = refused(workdir, "eval", "--table", "2", "--policy", "base", "--depth-hybrid")
    assert "the depth shield needs a vision residual" in message


def test_render_depth_shield_needs_a_vision_residual_and_the_planner_a_margin(workdir):
    message = refused(workdir, "render", "--policy", "ik", "--depth-shield-m", "0.01")
    assert "the depth shield needs a vision residual" in message
    message = refused(workdir, "render", "--policy", "residual-1view", "--depth-planner")
    assert "--depth-planner needs --depth-shield-m" in message


def test_eval_rrt_without_ompl_says_what_to_install(workdir, monkeypatch):
    for module in ("ompl", "ompl.base", "ompl.geometric", "ompl.util"):
        monkeypatch.setitem(sys.modules, module, None)  # `import` then raises ImportError
    message = refused(workdir, "eval", "--policy", "rrt", "--table", "2", "--num-tasks", "1")
    assert "--policy rrt needs OMPL 2 (`pip install ompl`, or clamgen[planning])" in message


def test_output_names_come_from_the_policy(workdir):
    assert policy_label("residual-2views") == "residual-2views"
    assert policy_label(Path("runs/joint-seed3/policy.pt")) == "joint-seed3"
    assert policy_label(Path("sweep/clamgen-2views/seed1/policy.pt")) == "clamgen-2views_seed1"
    assert policy_label(Path("exports/best.pt")) == "best"
    assert output_stem(RenderConfig(policy="ik"), "ik") == Path("runs/videos/ik")


def test_eval_writes_under_the_run_name_and_keeps_an_existing_result(workdir):
    run = workdir / "runs" / "joint-seed3"
    run.mkdir(parents=True)
    shutil.copy(ckpt.resolve_policy_path("base"), run / "policy.pt")
    argv = ["eval", "--policy", "runs/joint-seed3/policy.pt", "--num-tasks", "1"]
    argv += ["--speeds", "0"]
    cli.main(argv)
    result = workdir / "runs" / "eval" / "table1_joint-seed3.json"
    assert result.is_file() and result.with_suffix(".md").is_file()
    message = refused(workdir, *argv)
    assert f"{Path('runs/eval/table1_joint-seed3.json')} exists; pass --overwrite" in message
    result.write_text("{}")
    cli.main([*argv, "--overwrite"])
    assert result.read_text() != "{}"


def test_render_keeps_an_existing_video(workdir):
    videos = workdir / "runs" / "videos"
    videos.mkdir(parents=True)
    (videos / "ik.mp4").write_bytes(b"an earlier video")
    message = refused(workdir, "render", "--policy", "ik", "--num-episodes", "1")
    assert f"{Path('runs/videos/ik.mp4')} exists; pass --overwrite to replace it" in message


def test_render_demo_view_and_export_refuse_a_negative_seed(workdir):
    assert "--seed must be >= 0, got -5" in refused(
        workdir, "render", "--policy", "ik", "--seed", "-5"
    )
    assert "--seed must be >= 0, got -1" in refused(workdir, "demo", "--seed", "-1")
    assert "--seed must be >= 0, got -2" in refused(workdir, "export-scene", "--seed", "-2")
    # Before the viewer looks for a display.
    assert "--seed must be >= 0, got -3" in refused(workdir, "view", "--seed", "-3")


def test_counts_below_one_are_refused_by_their_flag(workdir):
    assert "--num-tasks must be >= 1, got 0" in refused(
        workdir, "eval", "--table", "2", "--policy", "ik", "--num-tasks", "0"
    )
    assert "--num-episodes must be >= 1, got 0" in refused(workdir, "demo", "--num-episodes", "0")
    flags = ("--policy", "ik", "--num-episodes", "0")
    assert "--num-episodes must be >= 1, got 0" in refused(workdir, "render", *flags)
    assert "--fps must be >= 1, got 0" in refused(workdir, "render", "--policy", "ik", "--fps", "0")


def test_render_refuses_a_bad_outcome_search(workdir):
    flags = ("--outcome", "failure", "--num-episodes", "2", "--max-tries", "1")
    message = refused(workdir, "render", "--policy", "ik", *flags)
    assert "--max-tries (1) must be >= --num-episodes (2)" in message


def test_eval_rrt_on_table1_says_how_it_plans(workdir, capsys):
    pytest.importorskip("ompl")
    out = workdir / "rrt"
    cli.main(["eval", "--policy", "rrt", "--num-tasks", "1", "--speeds", "0.1", "--out", str(out)])
    assert "note: RRT plans once, open loop" in capsys.readouterr().out
    note = "it is the baseline for static obstacle tasks (Table 2, `--table 2`)"
    assert note in out.with_suffix(".md").read_text()
    assert note in out.with_suffix(".json").read_text()
    out = workdir / "depth_rrt"
    args = ["--policy", "depth-rrt-1view", "--num-tasks", "1", "--speeds", "0.1"]
    cli.main(["eval", *args, "--out", str(out)])
    assert "note: RRT on the depth map plans at the first step to meet" in capsys.readouterr().out
    assert "planning takes no simulated time" in out.with_suffix(".md").read_text()


# ---------------------------------------------------------------- --debug, exit status
def test_debug_shows_the_error_itself(workdir):
    with pytest.raises(ValueError, match=r"agent.gamma must be in \[0, 1\], got 2"):
        cli.main(["--debug", "train", "--run-dir", "run", "--agent.gamma", "2"])
    (workdir / "runs" / "videos").mkdir(parents=True)
    (workdir / "runs" / "videos" / "ik.gif").write_bytes(b"")
    with pytest.raises(FileExistsError, match=r"ik\.gif exists; pass --overwrite"):
        cli.main(["render", "--policy", "ik", "--debug"])


def test_the_console_command_prints_one_line_and_exits_1(workdir):
    command = [sys.executable, "-m", "clamgen", "train", "--run-dir", "run"]
    result = subprocess.run(
        [*command, "--agent.batch-size", "0"], capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 1
    assert result.stderr.strip().splitlines()[-1] == (
        "clamgen train: agent.batch_size must be an integer >= 1, got 0"
    )
    assert "Traceback" not in result.stderr
    assert not (workdir / "run").exists()
    result = subprocess.run(
        [*command, "--agent.batch-size", "0", "--debug"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 1 and "Traceback (most recent call last)" in result.stderr


# ------------------------------------------------------------- Task and gym.make boundary
GOOD = {
    "start_joints": np.zeros(6),
    "target_position_m": np.array([0.5, 0.0, 0.2]),
    "target_velocity_mps": np.zeros(3),
}


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"target_position_m": [np.nan, 0, 0.2]}, "Task.target_position_m must be 3 finite"),
        ({"start_joints": np.full(6, 100.0)}, "Task.start_joints must lie within the joint limits"),
        ({"start_joints": np.full(6, np.nan)}, "Task.start_joints must be 6 finite numbers"),
        ({"start_joints": np.zeros(5)}, "Task.start_joints must be 6 finite numbers"),
        ({"target_velocity_mps": [0, np.nan, 0]}, "Task.target_velocity_mps must be 3 finite"),
        ({"speed": "zzz"}, "Task.speed: target speed must be a number (m/s) or 'variable'"),
        ({"speed": -1.0}, "Task.speed: target speed must be finite and >= 0 m/s, got -1.0"),
        ({"obstacles": None}, "Task.obstacles must be a clamgen.sim.scene.Obstacles"),
        (
            {"obstacles": Obstacles(np.array([7]), np.zeros((1, 3)), np.ones((1, 3)))},
            "Task.obstacles.kinds must be OBSTACLE_BOX (0) or OBSTACLE_CYLINDER (1), got [7]",
        ),
        (
            {"obstacles": Obstacles(np.array([0]), np.full((1, 3), np.nan), np.ones((1, 3)))},
            "Task.obstacles.positions_m must be (1, 3) finite numbers",
        ),
    ],
)
def test_task_refuses_bad_values(change, expected):
    with pytest.raises(ValueError) as error:
        Task(**{**GOOD, **change})
    assert expected in str(error.value) and "\n" not in str(error.value)


def test_task_accepts_lists_and_stores_arrays():
    task = Task([0.0] * 6, [0.5, 0.0, 0.2], [0.0, 0.0, 0.0], speed=0)
    assert task.start_joints.dtype == np.float64 and task.start_joints.shape == (6,)
    assert task.speed == 0.0


@pytest.mark.parametrize(
    ("kwargs", "expected"),
    [
        (
            {"num_views": 2},
            "num_views=2 renders images, but obs_mode='joints' observes none: pass "
            "obs_mode='images' or 'both'",
        ),
        ({"num_views": 1.5, "obs_mode": "both"}, "num_views must be an integer in 0..4, got 1.5"),
        (
            {"num_views": 1, "obs_mode": "both", "image_size": 10000},
            "image_size must be an integer in 8..1024, got 10000",
        ),
        ({"num_obstacles": 2.5}, "num_obstacles must be an integer in 0..4, got 2.5"),
        ({"collision_margin_m": np.nan}, "collision_margin_m must be a finite number >= 0"),
    ],
)
def test_gym_make_refuses_bad_options(kwargs, expected):
    with pytest.raises(ValueError) as error:
        gym.make("CLAMGen/ReachObstacles-v0", **kwargs)
    assert expected in str(error.value) and "\n" not in str(error.value)


def test_reset_refuses_a_task_that_is_not_one():
    env = gym.make("CLAMGen/Reach-v0")
    with pytest.raises(TypeError, match="options\\['task'\\] must be a clamgen Task"):
        env.reset(options={"task": {"start_joints": np.zeros(6)}})
    env.close()
