"""Other goal-conditioned envs as first-class: `--env.env-id module:id`, only the metrics the env
provides, and `clamgen eval` / `clamgen render` on the env a policy was trained on (or one
line saying why not). The env is `point_reach_env:PointReach-v0` beside this file: 3 action
dimensions, no collision reports, like panda-gym's PandaReach."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from clamgen.cli import main
from clamgen.experiments.evaluate import (
    check_policy_fits,
    evaluate,
    make_goal_env,
    summarize,
)

ENV_ID = "point_reach_env:PointReach-v0"
CLAMGEN_ONLY = ("collision_rate", "mean_tip_path_m")


class TowardsGoal:
    """Moves the point straight at the goal."""

    def reset(self, env=None) -> None:
        pass

    def act(self, obs):
        return np.clip((obs["desired_goal"] - obs["achieved_goal"]) * 10, -1, 1)


def test_module_id_imports_the_module_that_registers_the_env():
    env = make_goal_env(ENV_ID)
    assert env.action_space.shape == (3,)
    env.close()


@pytest.mark.parametrize(
    ("env_id", "render_mode", "message"),
    [
        ("no_such_module:PointReach-v0", None, "cannot import 'no_such_module'"),
        ("point_reach_env:NoSuchEnv-v0", None, "NoSuchEnv"),
        ("CartPole-v1", None, "is not goal-conditioned"),
        ("point_reach_env:PointReachNoFrames-v0", "rgb_array", "cannot render 'rgb_array'"),
    ],
)
def test_envs_that_cannot_serve_are_refused_in_one_line(env_id, render_mode, message):
    with pytest.raises(ValueError, match=message) as error:
        make_goal_env(env_id, render_mode=render_mode)
    assert "\n" not in str(error.value)


def test_metrics_the_env_does_not_provide_are_left_out():
    from clamgen.baselines import IKInterpolationPolicy
    from clamgen.envs import ReachEnv

    env = make_goal_env(ENV_ID)
    summary = summarize(evaluate(env, TowardsGoal(), range(3)))
    assert summary["success_rate"] == 1.0
    assert not set(CLAMGEN_ONLY) & set(summary)
    reach = summarize(evaluate(ReachEnv(), IKInterpolationPolicy(), range(2)))
    assert set(CLAMGEN_ONLY) <= set(reach)


def _rewrite_env_id(policy_file, env_id, out):
    payload = torch.load(policy_file, weights_only=True)
    config = json.loads(payload["config"])
    config["env"]["env_id"] = env_id
    payload["config"] = json.dumps(config)
    torch.save(payload, out)
    return out


@pytest.mark.timeout(900)
def test_train_eval_and_render_on_another_env(tmp_path, capsys):
    run = tmp_path / "run"
    main(
        [
            "train",
            *("--env.env-id", ENV_ID, "--env.num-envs", "2", "--run-dir", str(run)),
            *("--loop.total-env-steps", "60", "--loop.learning-starts", "40"),
            *("--loop.eval-every-steps", "0", "--loop.num-eval-episodes", "2"),
            *("--loop.log-every-steps", "20", "--loop.checkpoint-every-steps", "0"),
            *("--agent.batch-size", "16", "--replay.capacity", "500"),
        ]
    )
    with (run / "metrics.csv").open() as f:
        logged = {row["metric"] for row in csv.DictReader(f)}
    assert "eval/success_rate" in logged
    assert not {f"eval/{key}" for key in CLAMGEN_ONLY} & logged
    policy_file = run / "policy.pt"

    out = tmp_path / "eval"
    main(["eval", "--policy", str(policy_file), "--num-tasks", "2", "--out", str(out)])
    result = json.loads(out.with_suffix(".json").read_text())
    assert result["env_id"] == ENV_ID and result["num_tasks"] == 2
    assert 0.0 <= result["success_rate"] <= 1.0
    assert not set(CLAMGEN_ONLY) & set(result)

    video = tmp_path / "video"
    main(["render", "--policy", str(policy_file), "--num-episodes", "1", "--out", str(video)])
    summary = json.loads(video.with_suffix(".json").read_text())
    assert summary["env_id"] == ENV_ID
    assert summary["episodes"][0]["steps"] >= 1 and "collided" not in summary["episodes"][0]
    import imageio.v3 as iio

    frames = iio.imread(video.with_suffix(".mp4"))
    assert len(frames) >= summary["episodes"][0]["steps"] + 1
    assert frames.std() > 1  # the env's own frames, captioned

    blind = _rewrite_env_id(
        policy_file, "point_reach_env:PointReachNoFrames-v0", tmp_path / "blind.pt"
    )
    with pytest.raises(SystemExit, match="cannot render 'rgb_array'") as error:
        main(["render", "--policy", str(blind), "--out", str(tmp_path / "blind")])
    assert "\n" not in str(error.value)
    gone = _rewrite_env_id(policy_file, "no_such_module:PointReach-v0", tmp_path / "gone.pt")
    with pytest.raises(SystemExit, match="cannot import 'no_such_module'") as error:
        main(["eval", "--policy", str(gone), "--out", str(tmp_path / "gone")])
    assert "\n" not in str(error.value)

    # The policy writes 3 actions: a CLAMGen env (6 joints) is refused in one line.
    from clamgen.envs import ReachEnv
    from clamgen.experiments.policies import load_policy

    policy, _, _ = load_policy(policy_file)
    with pytest.raises(ValueError, match=r"writes 3 actions.*takes \(6,\)"):
        check_policy_fits(policy, ReachEnv(), "CLAMGen/Reach-v0")


def test_clamgen_only_options_are_refused_for_another_env(tmp_path):
    with pytest.raises(SystemExit, match=r"--env\.num-views applies to CLAMGen envs only"):
        main(
            [
                "train",
                *("--env.env-id", ENV_ID, "--env.num-views", "2"),
                *("--env.obs-mode", "both", "--run-dir", str(tmp_path / "run")),
            ]
        )
    assert not (tmp_path / "run").exists()
