"""DAgger from a privileged residual into a vision residual, end to end on tiny budgets."""

import copy
import dataclasses
import itertools
import json
import math

import numpy as np
import pytest
import torch
from test_stage2 import LOOP, image_config

from clamgen.agents.residual import imitation_error
from clamgen.experiments.config import config_to_json, load_preset
from clamgen.experiments.distill import (
    TARGET_CLIP,
    DistillConfig,
    Distiller,
    DistillSettings,
    pose_loss,
    scale_lengths,
    target_clearance_m,
)
from clamgen.experiments.lookahead import LookaheadPolicy
from clamgen.experiments.policies import load_policy
from clamgen.experiments.stage2 import Stage2Config, Stage2Trainer
from clamgen.experiments.sweep import read_validation
from clamgen.experiments.train import POLICY_NAME
from clamgen.replay import ReplayConfig


def privileged_config(run_dir, base_policy) -> Stage2Config:
    """A tiny privileged residual (true obstacle poses) on the mixed tasks."""
    preset = load_preset("residual-obstacles", Stage2Config)
    return dataclasses.replace(
        preset,
        run_dir=run_dir,
        base_policy=base_policy,
        env=dataclasses.replace(preset.env, env_id="CLAMGen/ReachMixed-v0", num_envs=2),
        agent=dataclasses.replace(preset.agent, batch_size=16, hidden_sizes=(32,)),
        replay=ReplayConfig(capacity=5_000),
        loop=LOOP,
    )


@pytest.fixture(scope="module")
def teacher(tmp_path_factory, base_policy):
    config = privileged_config(tmp_path_factory.mktemp("teacher") / "run", base_policy)
    Stage2Trainer(config).run(show_progress=False)
    return str(config.run_dir / POLICY_NAME)


def distill_config(tmp_path, base_policy, teacher, **settings) -> DistillConfig:
    student = image_config(tmp_path, base_policy)
    student = dataclasses.replace(
        student, env=dataclasses.replace(student.env, env_id="CLAMGen/ReachMixed-v0")
    )
    return DistillConfig(student=student, distill=tiny_settings(teacher, **settings))


def tiny_settings(teacher, **settings) -> DistillSettings:
    """Two iterations of three episodes and four regression steps, unless `settings` say."""
    defaults = dict(
        teacher=teacher,
        iterations=2,
        episodes_per_iteration=3,
        updates_per_iteration=4,
        num_eval_episodes=2,
    )
    return DistillSettings(**{**defaults, **settings})


def test_dagger_labels_every_state_with_the_teacher_and_writes_a_policy(
    tmp_path,
    base_policy,
    teacher,
):
    config = distill_config(tmp_path, base_policy, teacher)
    distiller = Distiller(config)
    summary = distiller.run(show_progress=False)
    assert [row["iteration"] for row in summary["iterations"]] == [0, 1]
    assert summary["iterations"][0]["teacher_share"] == 1.0
    assert summary["iterations"][1]["teacher_share"] == 0.5
    # Every stored state carries the teacher's (clipped) pre-squash mean for that state.
    data = distiller.data.arrays
    assert len(data["label"]) == len(data["images"]) >= 6  # 3 episodes of >= 1 step, twice
    assert np.abs(data["label"]).max() <= TARGET_CLIP
    index = np.arange(5)
    obs = {k: data[k][index] for k in ("observation", "desired_goal")}
    obs["obstacles"] = data["obstacles"][index]
    expected = np.clip(distiller.teacher.mean_action(obs), -TARGET_CLIP, TARGET_CLIP)
    np.testing.assert_allclose(data["label"][index], expected, atol=1e-5)
    # The student's policy file is a residual policy that eval and render load by path.
    policy, _, env_kwargs = load_policy(config.student.run_dir / POLICY_NAME)
    assert env_kwargs["num_views"] == 2 and not env_kwargs["include_obstacle_state"]
    obs = {k: data[k][0] for k in ("images", "observation", "achieved_goal", "desired_goal")}
    assert policy.act(obs).shape == (6,)


def test_regression_moves_the_student_towards_the_labels(
    tmp_path,
    base_policy,
    teacher,
):
    distiller = Distiller(distill_config(tmp_path, base_policy, teacher, pose_weight=1.0))
    chunk, _ = distiller.collect_iteration(1.0, 0, show_progress=False)
    distiller.data.add(chunk)
    index = np.arange(min(len(distiller.data), 16))
    obs, labels = distiller.data.batch(index)
    torch.manual_seed(0)
    with torch.no_grad():
        before = float(distiller.student.imitation_loss(obs, torch.as_tensor(labels))[0])
    distiller.regress(60, 0, show_progress=False)
    with torch.no_grad():
        losses = [distiller.student.imitation_loss(obs, torch.as_tensor(labels))[0] for _ in "ab"]
    after = np.mean([float(loss) for loss in losses])
    assert after < before


def test_a_rerun_resumes_after_the_last_iteration_and_refuses_other_settings(
    tmp_path,
    base_policy,
    teacher,
):
    first = distill_config(tmp_path, base_policy, teacher, iterations=1)
    Distiller(first).run(show_progress=False)
    # Same settings, one more iteration: only iteration 1 runs, on iteration 0's data too.
    more = distill_config(tmp_path, base_policy, teacher, iterations=2)
    with pytest.raises(ValueError, match="another configuration"):
        Distiller(distill_config(tmp_path, base_policy, teacher, lr=1e-3)).run(False)
    # A run written before a setting existed resumes: the missing setting reads as its default.
    path = first.student.run_dir / "config.json"
    saved = json.loads(path.read_text())
    del saved["distill"]["stop_at_collision"]
    path.write_text(json.dumps(saved))
    resumed = Distiller(more)
    summary = resumed.run(show_progress=False)
    assert [row["iteration"] for row in summary["iterations"]] == [0, 1]
    first_samples = summary["iterations"][0]["samples"]
    assert summary["iterations"][1]["samples"] > first_samples  # iteration 0's data kept
    assert (first.student.run_dir / "data" / "iteration1.npz").exists()
    # metrics.csv holds each iteration's validation once, against the labelled states so far.
    steps, success = read_validation(first.student.run_dir)
    assert steps == [row["samples"] for row in summary["iterations"]]
    assert success == [row["validation/success_rate"] for row in summary["iterations"]]


def test_the_teacher_must_be_privileged_and_settings_are_checked(
    tmp_path,
    base_policy,
    teacher,
):
    student = image_config(tmp_path, base_policy)
    with pytest.raises(ValueError, match=r"distill\.teacher is required"):
        Distiller(DistillConfig(student=student))
    with pytest.raises(ValueError, match="not a privileged residual"):
        Distiller(DistillConfig(student=student, distill=DistillSettings(teacher="residual-1view")))
    with pytest.raises(ValueError, match=r"distill\.iterations"):
        DistillSettings(iterations=0)
    with pytest.raises(ValueError, match=r"distill\.action_loss_weight"):
        DistillSettings(action_loss_weight=-1.0)
    with pytest.raises(ValueError, match=r"distill\.action_loss_kind"):
        DistillSettings(action_loss_kind="huber")
    with pytest.raises(ValueError, match="both 0"):
        DistillSettings(pre_squash_loss_weight=0.0)


def test_the_loss_after_the_tanh_weighs_errors_by_the_actions_they_change():
    # One pre-squash error of 1, between two saturated values and around zero.
    saturated = imitation_error(torch.tensor([[2.5]]), torch.tensor([[3.5]]), 0.0, 1.0)
    centred = imitation_error(torch.tensor([[0.0]]), torch.tensor([[1.0]]), 0.0, 1.0)
    assert float(centred) == pytest.approx(np.tanh(1.0) ** 2)
    assert float(saturated) < float(centred) / 100
    for mean, target in (([[2.5]], [[3.5]]), ([[0.0]], [[1.0]])):
        assert float(imitation_error(torch.tensor(mean), torch.tensor(target))) == 1.0
    # The terms add with their weights.
    mean, target = torch.tensor([[0.2, -2.9]]), torch.tensor([[-0.4, 3.0]])
    both = imitation_error(mean, target, 0.05, 2.0)
    parts = 0.05 * imitation_error(mean, target) + 2.0 * imitation_error(mean, target, 0.0, 1.0)
    assert float(both) == pytest.approx(float(parts))
    # The absolute error after the tanh: the median of labels that disagree, not their mean.
    labels = torch.tensor([[-2.0], [-2.0], [1.0]])

    def best(absolute: bool) -> float:
        grid = torch.linspace(-3, 3, 601)[:, None, None].expand(-1, 3, 1)
        costs = [float(imitation_error(m, labels, 0.0, 1.0, absolute)) for m in grid]
        return float(grid[int(np.argmin(costs)), 0, 0])

    assert best(absolute=True) == pytest.approx(-2.0)
    mean_action = np.arctanh(np.mean(np.tanh([-2.0, -2.0, 1.0])))  # -0.41, between the two
    assert best(absolute=False) == pytest.approx(mean_action, abs=0.01)


def test_a_student_regresses_with_the_loss_after_the_tanh(tmp_path, base_policy, teacher):
    student = privileged_config(tmp_path / "student", base_policy)
    weights = dict(pre_squash_loss_weight=0.05, action_loss_weight=1.0)
    settings = tiny_settings(teacher, iterations=1, **weights)
    distiller = Distiller(DistillConfig(student=student, distill=settings))
    chunk, _ = distiller.collect_iteration(1.0, 0, show_progress=False)
    distiller.data.add(chunk)
    obs, labels = distiller.data.batch(np.arange(min(len(distiller.data), 16)))
    labels = torch.as_tensor(labels)

    def action_error() -> float:
        # A privileged student: no random crops, the loss is a function of the weights.
        with torch.no_grad():
            return float(distiller.student.imitation_loss(obs, labels, 0.0, 1.0)[0])

    with torch.no_grad():
        mean = torch.as_tensor(distiller.student.mean_action(obs))
        loss = distiller.student.imitation_loss(obs, labels, 0.05, 1.0)[0]
    assert float(loss) == pytest.approx(float(imitation_error(mean, labels, 0.05, 1.0)), rel=1e-5)
    before = action_error()
    distiller.regress(60, 0, show_progress=False)
    assert action_error() < before


def test_a_privileged_student_imitates_from_true_poses_without_rendering(
    tmp_path,
    base_policy,
    teacher,
):
    student = privileged_config(tmp_path / "student", base_policy)
    settings = tiny_settings(teacher)
    distiller = Distiller(DistillConfig(student=student, distill=settings))
    before = [p.detach().clone() for p in distiller.pose_head.parameters()]
    summary = distiller.run(show_progress=False)
    assert [row["iteration"] for row in summary["iterations"]] == [0, 1]
    data = distiller.data.arrays
    assert "images" not in data
    assert len(data["obstacles"]) == len(data["label"]) >= 6
    # The pose loss is for vision students: the privileged student's pose head is untouched.
    for old, new in zip(before, distiller.pose_head.parameters(), strict=True):
        assert torch.equal(old, new)
    policy = load_policy(str(student.run_dir / POLICY_NAME))
    assert policy is not None


def test_collection_episodes_can_end_at_their_first_collision(tmp_path, base_policy, teacher):
    lengths = {}
    for stop in (False, True):
        config = distill_config(
            tmp_path / str(stop),
            base_policy,
            teacher,
            episodes_per_iteration=4,
            teacher_share=0.0,
            stop_at_collision=stop,
        )
        distiller = Distiller(config)
        for env in distiller.envs:  # every episode "collides" at its second step
            env_step, env_reset = env.step, env.reset
            steps = [0]

            def reset(*args, env_reset=env_reset, steps=steps, **kwargs):
                steps[0] = 0
                return env_reset(*args, **kwargs)

            def step(action, env_step=env_step, steps=steps):
                obs, reward, terminated, truncated, info = env_step(action)
                steps[0] += 1
                return obs, reward, terminated, truncated, {**info, "collision": steps[0] == 2}

            env.reset, env.step = reset, step
        chunk, stats = distiller.collect_iteration(0.0, 1, show_progress=False)
        lengths[stop] = len(chunk["label"])
        assert stats["rollout_success"] == 0.0
    assert lengths[True] == 4 * 2  # each episode: its first step and the colliding one
    assert lengths[False] > 4 * 2


def test_the_pose_loss_ignores_the_order_of_the_obstacles():
    poses = torch.arange(2 * 2 * 8, dtype=torch.float32).view(2, 2, 8)
    assert float(pose_loss(poses.flip(1), poses)) == 0.0
    assert float(pose_loss(poses + 1, poses)) == 1.0


def test_pose_lengths_are_measured_in_the_length_scale():
    pose = torch.tensor([[[1.0, 0.0, 0.5, -0.1, 0.2, 0.05, 0.05, 0.1]]])
    scaled = scale_lengths(pose, 0.05)
    expected = torch.tensor([[[1.0, 0.0, 10.0, -2.0, 4.0, 1.0, 1.0, 2.0]]])
    torch.testing.assert_close(scaled, expected)
    # A 5 cm error in one centre coordinate costs 1 / 8 (the mean over 8 numbers) at 0.05 m.
    off = pose.clone()
    off[0, 0, 2] += 0.05
    assert float(pose_loss(scale_lengths(off, 0.05), scaled)) == pytest.approx(1 / 8)
    with pytest.raises(ValueError, match=r"distill\.pose_length_scale_m"):
        DistillSettings(pose_length_scale_m=0.0)


@pytest.mark.parametrize("prefer_student", [False, True])
def test_a_lookahead_teacher_labels_with_its_plans_and_reports_their_cost(
    tmp_path, base_policy, teacher, prefer_student, monkeypatch
):
    config = distill_config(
        tmp_path,
        base_policy,
        teacher,
        lookahead_candidates=3,
        lookahead_horizon=6,
        lookahead_prefer_student=prefer_student,
        teacher_share=0.0,  # the student drives every episode after iteration 0
    )
    distiller = Distiller(config)
    preferences = []
    label = LookaheadPolicy.label

    def recording(self, obs, prefer=None):
        preferences.append(prefer)
        return label(self, obs, prefer)

    monkeypatch.setattr(LookaheadPolicy, "label", recording)
    summary = distiller.run(show_progress=False)
    first, second = summary["iterations"]
    assert first["teacher_success"] is not None and first["rollout_success"] is None
    assert first["lookahead_rollouts"] >= 3  # at least one rollout per episode
    assert second["lookahead_rollouts"] > 0
    assert np.abs(distiller.data.arrays["label"]).max() <= TARGET_CLIP
    # Only the student's episodes (iteration 1 on) carry its action as the preference.
    offered = [p for p in preferences if p is not None]
    assert bool(offered) == prefer_student
    assert all(p.shape == (6,) and np.abs(p).max() <= TARGET_CLIP + 1e-5 for p in offered)
    with pytest.raises(ValueError, match=r"distill\.lookahead_horizon"):
        DistillSettings(lookahead_horizon=0)
    with pytest.raises(ValueError, match=r"distill\.lookahead_margin_m"):
        DistillSettings(lookahead_margin_m=-0.01)
    with pytest.raises(ValueError, match=r"distill\.lookahead_least_offset"):
        DistillSettings(lookahead_least_offset=True, lookahead_prefer_student=True)


def test_the_least_offset_setting_reaches_the_teacher(tmp_path, base_policy, teacher):
    for least in (False, True):
        config = distill_config(
            tmp_path / str(least),
            base_policy,
            teacher,
            lookahead_candidates=3,
            lookahead_least_offset=least,
        )
        assert Distiller(config).lookahead.least_offset == least


def record_rates(distiller: Distiller) -> list[float]:
    """The learning rate of each later optimizer step of `distiller`, appended as it steps."""
    rates = []
    step = distiller.optimizer.step

    def record_lr_and_step(*args, **kwargs):
        rates.append(distiller.optimizer.param_groups[0]["lr"])
        return step(*args, **kwargs)

    distiller.optimizer.step = record_lr_and_step
    return rates


def test_a_finished_run_is_polished_with_a_decaying_learning_rate_and_keeps_the_best(
    tmp_path,
    base_policy,
    teacher,
):
    Distiller(distill_config(tmp_path, base_policy, teacher, iterations=1)).run(False)
    polish = dict(iterations=1, final_updates=8)
    polishing = Distiller(distill_config(tmp_path, base_policy, teacher, **polish))
    rates = record_rates(polishing)
    summary = polishing.run(show_progress=False)
    # No new iteration: 8 regression steps from lr down towards 0, then validation.
    assert [row["iteration"] for row in summary["iterations"]] == [0]
    assert len(rates) == 8 and rates[0] == pytest.approx(3e-4)
    assert all(a > b for a, b in itertools.pairwise(rates)) and rates[-1] < 3e-5
    assert polishing.optimizer.param_groups[0]["lr"] == pytest.approx(3e-4)
    final = summary["final"]
    assert final["updates"] == 8 and "validation/success_rate" in final
    run_dir = tmp_path / "run"
    assert (run_dir / "policy_final.pt").exists()
    best = max(
        summary["iterations"][0]["validation/success_rate"], final["validation/success_rate"]
    )
    assert summary["validation/success_rate"] == best
    # Rerun: nothing left to do; more iterations after polishing are refused.
    again = Distiller(distill_config(tmp_path, base_policy, teacher, **polish))
    assert again.run(show_progress=False)["final"] == final
    with pytest.raises(ValueError, match="polished"):
        Distiller(
            distill_config(tmp_path, base_policy, teacher, **{**polish, "iterations": 2})
        ).run(False)


def test_a_regression_in_chunks_follows_one_cosine_and_restores_the_rate(
    tmp_path, base_policy, teacher
):
    distiller = Distiller(distill_config(tmp_path, base_policy, teacher, iterations=1))
    distiller.run(False)
    rates = record_rates(distiller)
    for first in (0, 4, 8):  # three chunks of one 12-step cosine, as offline.py --cosine runs
        distiller.regress(4, "offline", show_progress=False, decay_over=(first, 12))
        assert distiller.optimizer.param_groups[0]["lr"] == pytest.approx(3e-4)
    expected = [0.5 * 3e-4 * (1 + math.cos(math.pi * k / 12)) for k in range(12)]
    assert rates == pytest.approx(expected)
    with pytest.raises(ValueError, match="do not fit"):
        distiller.regress(4, "offline", show_progress=False, decay_over=(10, 12))


def test_a_regression_reports_its_last_batchs_loss_and_the_mean_over_its_batches(
    tmp_path, base_policy, teacher
):
    distiller = Distiller(distill_config(tmp_path, base_policy, teacher, iterations=1))
    distiller.run(False)
    row = distiller.history[0]
    assert np.isfinite(row["loss"]) and np.isfinite(row["loss_mean"])
    state = copy.deepcopy(distiller.regression_state())
    whole = distiller.regress(5, "offline", show_progress=False)
    distiller.load_regression_state(state)  # the same five batches, one step at a time
    steps = [distiller.regress(1, "offline", show_progress=False) for _ in range(5)]
    assert whole.batches == 5 and all(step.batches == 1 for step in steps)
    assert all(step.last == step.mean for step in steps)
    assert whole.last == steps[-1].last
    assert whole.mean == pytest.approx(np.mean([step.last for step in steps]), rel=1e-6)
    assert distiller.regress(0, "offline", show_progress=False) == (None, None, 0)


def test_weight_decay_shrinks_each_weight_beside_adams_step(tmp_path, base_policy, teacher):
    distiller = Distiller(
        distill_config(tmp_path, base_policy, teacher, iterations=1, weight_decay=0.5)
    )
    distiller.run(False)
    assert all(group["weight_decay"] == 0.5 for group in distiller.optimizer.param_groups)
    state = copy.deepcopy(distiller.regression_state())
    params = list(distiller.student.actor.parameters())
    before = [p.detach().clone() for p in params]
    after = {}
    for decay in (0.0, 0.5):  # one regression step from the same state, batch and crops
        distiller.load_regression_state(copy.deepcopy(state))
        for group in distiller.optimizer.param_groups:
            group["weight_decay"] = decay
        distiller.regress(1, 0, show_progress=False)
        after[decay] = [p.detach().clone() for p in params]
    lr = distiller.config.distill.lr
    stepped = [i for i, p in enumerate(params) if p.grad is not None]
    assert stepped
    for i in stepped:  # AdamW: the same Adam step, and each weight shrunk by lr * decay
        torch.testing.assert_close(after[0.5][i], after[0.0][i] - lr * 0.5 * before[i])
    with pytest.raises(ValueError, match="weight_decay"):
        tiny_settings(teacher, weight_decay=-1.0)


def test_a_student_with_candidate_actions_trains_saves_and_acts(tmp_path, base_policy, teacher):
    student = privileged_config(tmp_path / "student", base_policy)
    student = dataclasses.replace(
        student, agent=dataclasses.replace(student.agent, actor_components=3)
    )
    settings = tiny_settings(teacher, iterations=1, updates_per_iteration=20)
    distiller = Distiller(DistillConfig(student=student, distill=settings))
    distiller.run(show_progress=False)
    obs, labels = distiller.data.batch(np.arange(8))
    loss, _ = distiller.student.imitation_loss(obs, torch.as_tensor(labels))
    assert torch.isfinite(loss)
    # The policy file rebuilds the three candidates and acts with the chosen one, as trained.
    policy, _, _ = load_policy(str(student.run_dir / POLICY_NAME))
    single = {k: v[0] for k, v in obs.items()}
    assert np.allclose(policy.act(single), distiller.student.act(single, deterministic=True))
    # RL trains one Gaussian: candidate actions are refused there.
    with pytest.raises(ValueError, match="actor_components > 1 is for distilled students"):
        Stage2Trainer(student)


def test_a_student_reading_its_previous_action_stores_trains_and_acts_on_it(
    tmp_path, base_policy, teacher
):
    student = privileged_config(tmp_path / "student", base_policy)
    student = dataclasses.replace(
        student,
        env=dataclasses.replace(student.env, previous_action=True),
        agent=dataclasses.replace(student.agent, previous_action=True),
    )
    settings = tiny_settings(teacher, updates_per_iteration=20)
    distiller = Distiller(DistillConfig(student=student, distill=settings))
    distiller.run(show_progress=False)
    previous = distiller.data.arrays["previous_action"]
    assert previous.shape == (len(distiller.data), 6) and np.any(previous != 0)
    # The policy file's env options give the key, and the action depends on it.
    policy, _, env_kwargs = load_policy(str(student.run_dir / POLICY_NAME))
    assert env_kwargs["previous_action"] is True
    obs, _ = distiller.data.batch(np.arange(1))
    single = {k: v[0] for k, v in obs.items()}
    assert np.allclose(policy.act(single), distiller.student.act(single, deterministic=True))
    flipped = single | {"previous_action": -single["previous_action"] + 0.5}
    assert not np.allclose(policy.act(single), policy.act(flipped))
    # Without the env's observation the agent has nothing to read; reversed episodes would
    # keep the forward previous actions, so RL refuses reversible HER with it.
    with pytest.raises(ValueError, match="needs env"):
        Stage2Trainer(dataclasses.replace(student, env=privileged_config(tmp_path, "x").env))
    reversible = dataclasses.replace(student, replay=ReplayConfig(reversible_her=True))
    with pytest.raises(ValueError, match="reversible HER"):
        Stage2Trainer(reversible)


def test_target_clearance_is_the_distance_to_the_nearest_obstacle_box():
    # [is_box, is_cylinder, x, y, z, hx, hy, hz]: a 10 cm cube at the origin, one at x = 1 m.
    obstacles = np.array([[1, 0, 0, 0, 0, 0.05, 0.05, 0.05], [1, 0, 1, 0, 0, 0.05, 0.05, 0.05]])
    goals = np.array([[0.08, 0, 0], [0.5, 0, 0], [0.0, 0.01, 0.0], [0.08, 0.09, 0.0]])
    clearance = target_clearance_m(goals, np.repeat(obstacles[None], len(goals), axis=0))
    np.testing.assert_allclose(clearance, [0.03, 0.45, 0.0, 0.05], atol=1e-12)


def test_batches_draw_states_near_their_target_more_often(tmp_path, base_policy, teacher):
    uniform = Distiller(distill_config(tmp_path / "u", base_policy, teacher))
    weighted = Distiller(
        distill_config(tmp_path / "w", base_policy, teacher, near_target_weight=4.0)
    )
    n = 1000
    goals = np.zeros((n, 3))
    goals[:, 0] = np.where(np.arange(n) % 4 == 0, 0.06, 0.5)  # every 4th: 1 cm from the box
    box = np.array([1, 0, 0, 0, 0, 0.05, 0.05, 0.05])
    for distiller in (uniform, weighted):
        distiller.data.arrays = {
            "desired_goal": goals,
            "obstacles": np.tile(box, (n, 2, 1)),
            "label": np.zeros((n, 6)),
        }
    # Weight 1 keeps the random stream of runs made before the setting existed.
    expected = np.random.default_rng([0, 1]).integers(0, n, 64)
    np.testing.assert_array_equal(uniform.batch_index(64), expected)
    drawn = weighted.batch_index(40_000)
    near_share = np.mean(drawn % 4 == 0)
    assert abs(near_share - 4 / 7) < 0.02  # weight 4 for a quarter of the states: 4 / (4 + 3)
    part = weighted.draw(600, 1000, 10_000)
    assert part.min() >= 600 and part.max() < 1000
    assert abs(np.mean(part % 4 == 0) - 4 / 7) < 0.03
    with pytest.raises(ValueError, match=r"distill\.near_target_weight"):
        DistillSettings(near_target_weight=0.0)
    with pytest.raises(ValueError, match=r"distill\.near_target_m"):
        DistillSettings(near_target_m=-0.01)


def test_batches_draw_states_whose_tip_is_near_the_target_more_often(
    tmp_path, base_policy, teacher
):
    both = dict(near_tip_weight=3.0, near_target_weight=2.0)
    weighted = Distiller(distill_config(tmp_path, base_policy, teacher, **both))
    n = 1200
    goals = np.zeros((n, 3))
    goals[:, 0] = np.where(np.arange(n) % 2 == 0, 0.06, 0.5)  # every 2nd: 1 cm from the box
    tips = goals.copy()
    tips[:, 1] = np.where(np.arange(n) % 3 == 0, 0.04, 0.2)  # every 3rd: tip 4 cm from its goal
    box = np.array([1, 0, 0, 0, 0, 0.05, 0.05, 0.05])
    weighted.data.arrays = {
        "desired_goal": goals,
        "achieved_goal": tips,
        "obstacles": np.tile(box, (n, 2, 1)),
        "label": np.zeros((n, 6)),
    }
    drawn = weighted.batch_index(60_000)
    # Weights 3 (tip near) and 2 (target near) multiply: per six states 6 + 3 + 2 + 1 + 2 + 1.
    assert abs(np.mean(drawn % 3 == 0) - 9 / 15) < 0.02
    assert abs(np.mean(drawn % 6 == 0) - 6 / 15) < 0.02
    with pytest.raises(ValueError, match=r"distill\.near_tip_weight"):
        DistillSettings(near_tip_weight=0.0)
    with pytest.raises(ValueError, match=r"distill\.near_tip_m"):
        DistillSettings(near_tip_m=-0.01)


def test_pose_head_starts_from_the_distill_seed(tmp_path, base_policy, teacher):
    # Its initial weights used to come from torch's global stream, unseeded in a regression
    # script, so two regressions of the same settings differed.
    heads = []
    for name, global_seed, seed in (("a", 1, 3), ("b", 2, 3), ("c", 1, 4)):
        torch.manual_seed(global_seed)  # the global stream plays no part
        config = distill_config(tmp_path / name, base_policy, teacher, seed=seed)
        heads.append(Distiller(config).pose_head.weight.detach())
    assert torch.equal(heads[0], heads[1])
    assert not torch.equal(heads[0], heads[2])


def test_collision_head_learns_beside_the_student_and_acts_as_a_shield(
    tmp_path, base_policy, teacher, results_script
):
    from clamgen.experiments.learned_shield import HEAD_NAME, LearnedShieldPolicy

    collisions = results_script("stage2/distill/collisions.py")

    config = distill_config(tmp_path, base_policy, teacher)
    distiller = collisions.CollisionDistiller(config)
    chunk, _ = distiller.collect_iteration(1.0, 0, show_progress=False)
    distiller.data.add(chunk)
    n = len(distiller.data)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (n, 4, 6)).astype(np.float32)
    collided = actions[..., 0] > 0.3  # a rule the head can learn from the action alone
    distiller.attach_collisions(actions, collided)
    index = np.arange(n)
    obs, _ = distiller.data.batch(index)

    def head_loss() -> float:
        with torch.no_grad():
            visual = distiller.student.critic.encoder(distiller.student._visual(obs, False))
            return float(distiller.extra_loss(index, obs, visual))

    # The collision loss's gradient reaches the encoder through the encoding it is given.
    encoder = distiller.student.critic.encoder
    encoder.zero_grad(set_to_none=True)
    distiller.extra_loss(index, obs, encoder(distiller.student._visual(obs, False))).backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in encoder.parameters())
    before = head_loss()
    distiller.regress(80, 0, show_progress=False)
    assert head_loss() < before
    distiller.save_head(tmp_path)
    shield = LearnedShieldPolicy(distiller.student, tmp_path / HEAD_NAME, threshold=0.5)
    data = distiller.data.arrays
    state = {k: data[k][0] for k in ("images", "observation", "achieved_goal", "desired_goal")}
    assert shield.act(state).shape == (6,) and shield.num_steps == 1


def test_bin_head_learns_the_labels_bins_and_acts(tmp_path, base_policy, teacher, results_script):
    bins = results_script("stage2/distill/bins.py")
    distiller = bins.BinDistiller(distill_config(tmp_path, base_policy, teacher))
    chunk, _ = distiller.collect_iteration(1.0, 0, show_progress=False)
    distiller.data.add(chunk)
    distiller.attach_bins(3)
    labels = np.asarray(distiller.data.arrays["label"])
    centres = distiller.bin_head.centres.numpy()
    assert centres.shape == (3, 6)
    # each label's bin is its nearest centre
    nearest = ((labels[:, None] - centres[None]) ** 2).sum(-1).argmin(1)
    np.testing.assert_array_equal(distiller.assignment.numpy(), nearest)
    index = np.arange(len(distiller.data))
    obs, _ = distiller.data.batch(index)

    def bin_loss() -> float:
        with torch.no_grad():
            visual = distiller.student.critic.encoder(distiller.student._visual(obs, False))
            return float(distiller.extra_loss(index, obs, visual))

    before = bin_loss()
    distiller.regress(80, 0, show_progress=False)
    assert bin_loss() < before
    distiller.save_head(tmp_path)
    policy = bins.BinPolicy(distiller.student, tmp_path / bins.HEAD_NAME)
    data = distiller.data.arrays
    state = {k: data[k][0] for k in ("images", "observation", "achieved_goal", "desired_goal")}
    action = policy.act(state)
    assert action.shape == (6,) and np.abs(action).max() <= 1.0


def test_kmeans_finds_separated_clusters(results_script):
    bins = results_script("stage2/distill/bins.py")
    rng = np.random.default_rng(0)
    truth = np.array([[-2.0] * 6, [0.0] * 6, [2.0] * 6])
    points = np.concatenate([c + 0.05 * rng.normal(size=(200, 6)) for c in truth])
    centres = bins.kmeans(points, 3, seed=1)
    np.testing.assert_allclose(np.sort(centres[:, 0]), truth[:, 0], atol=0.02)
    assert len(np.unique(bins.nearest(points, centres))) == 3


def test_added_heads_start_from_the_seed_and_resume_with_the_regression(
    tmp_path, base_policy, teacher
):
    config = distill_config(tmp_path, base_policy, teacher)
    first, second = Distiller(config), Distiller(config)
    heads = [d.add_head("extra", lambda: torch.nn.Linear(3, 2)) for d in (first, second)]
    torch.testing.assert_close(heads[0].weight, heads[1].weight)
    assert any(heads[0].weight is p for g in first.optimizer.param_groups for p in g["params"])
    state = copy.deepcopy(first.regression_state())  # (as saved to a file)
    with torch.no_grad():
        heads[0].weight.add_(1.0)
    first.load_regression_state(state)
    torch.testing.assert_close(heads[0].weight, heads[1].weight)


def test_driver_noise_moves_the_student_off_its_path_and_the_teacher_labels_where_it_went(
    tmp_path, base_policy, teacher
):
    def collect(noise: float, share: float) -> tuple[Distiller, dict]:
        config = distill_config(tmp_path / f"{noise}-{share}", base_policy, teacher)
        config = dataclasses.replace(
            config, distill=dataclasses.replace(config.distill, driver_noise=noise)
        )
        distiller = Distiller(config)
        return distiller, distiller.collect_iteration(share, 0, show_progress=False)[0]

    (_, quiet), (distiller, noisy) = collect(0.0, 0.0), collect(0.5, 0.0)
    envs = 2  # image_config's envs, stepped together: each step stores one row per env
    # The same tasks (the noise has its own random stream), so the same first states ...
    np.testing.assert_array_equal(quiet["observation"][:envs], noisy["observation"][:envs])
    # ... and then other joints: the student's actions were jolted.
    second = slice(envs, 2 * envs)
    assert not np.allclose(quiet["observation"][second], noisy["observation"][second])
    # The teacher labels the states the noisy actions reached.
    obs = {k: noisy[k][: 2 * envs] for k in ("observation", "desired_goal", "obstacles")}
    expected = np.clip(distiller.teacher.mean_action(obs), -TARGET_CLIP, TARGET_CLIP)
    np.testing.assert_allclose(noisy["label"][: 2 * envs], expected, atol=1e-5)
    # Where the teacher drives, nothing changes.
    (_, driven), (_, driven_noisy) = collect(0.0, 1.0), collect(0.5, 1.0)
    for key, rows in driven.items():
        np.testing.assert_array_equal(rows, driven_noisy[key])
    with pytest.raises(ValueError, match=r"distill\.driver_noise"):
        DistillSettings(driver_noise=-0.1)


def test_an_offline_regression_saved_before_a_setting_existed_is_the_same_job(results_script):
    offline = results_script("stage2/distill/offline.py")
    student = json.loads(config_to_json(load_preset("residual-cpu", Stage2Config)))
    settings = dataclasses.asdict(DistillSettings(teacher="teacher.pt", seed=8))
    job = {"student": student, "distill": settings, "sources": [["run", None]], "updates": 9}
    older = copy.deepcopy(job)  # saved before these settings were added: their defaults
    del older["distill"]["driver_noise"], older["distill"]["near_tip_weight"]
    del older["student"]["agent"]["goal_offset"]
    assert offline.with_defaults(older) == offline.with_defaults(job)
    other = copy.deepcopy(older)
    other["distill"]["lr"] = 1e-3
    assert offline.with_defaults(other) != offline.with_defaults(job)
    named = copy.deepcopy(job)  # a setting named away from its default is another job
    named["distill"]["driver_noise"] = 0.3
    assert offline.with_defaults(named) != offline.with_defaults(older)


def test_an_offline_regression_stopped_between_chunks_resumes_to_the_same_student(
    tmp_path, base_policy, teacher, results_script, monkeypatch
):
    offline = results_script("stage2/distill/offline.py")
    monkeypatch.setattr(offline, "CHECKPOINT_UPDATES", 3)
    distiller = Distiller(distill_config(tmp_path, base_policy, teacher, iterations=1))
    distiller.run(False)
    start = copy.deepcopy(distiller.regression_state())
    student, settings = distiller.config.student, distiller.config.distill
    job = {
        "student": json.loads(config_to_json(student)),
        "distill": dataclasses.asdict(settings),
        "sources": [["run", None]],
        "updates": 5,
    }
    whole, seconds = offline.regress_resumably(distiller, 5, tmp_path / "whole", job)
    assert whole.batches == 2 and seconds > 0  # the last chunk's: updates 4 and 5
    expected = copy.deepcopy(distiller.student.state_dict())
    distiller.load_regression_state(copy.deepcopy(start))
    _, first = offline.regress_resumably(distiller, 3, tmp_path / "parts", job)  # then stopped
    with torch.no_grad():  # a fresh process: other weights and batches until it resumes
        for weight in distiller.student.actor.parameters():
            weight.add_(1.0)
    distiller.rng = np.random.default_rng(123)
    resumed, total = offline.regress_resumably(distiller, 5, tmp_path / "parts", job)
    assert resumed == whole and total > first  # the first process's time counts too
    weights = distiller.student.state_dict()
    assert weights.keys() == expected.keys()
    for name, value in weights.items():
        if isinstance(value, torch.Tensor):
            torch.testing.assert_close(value, expected[name], rtol=0, atol=0)
    with pytest.raises(SystemExit, match="other options"):
        offline.regress_resumably(distiller, 5, tmp_path / "parts", {**job, "updates": 6})


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (["--set", "seed=3"], "seed"),
        (["--set", "lookahead_candidates=4"], "lookahead_candidates"),
        (["--driver-noise", "0.2", "--set", "driver_noise=0.3"], "driver_noise"),
        (["--episodes", "8", "--set", "episodes_per_iteration=4"], "episodes_per_iteration"),
    ],
)
def test_a_continuation_refuses_a_setting_given_twice(
    tmp_path, results_script, capsys, flags, named
):
    continuation = results_script("stage2/distill/continue_dagger.py")
    with pytest.raises(SystemExit):
        continuation.main([str(tmp_path), str(tmp_path / "out"), "--seed", "9", *flags])
    message = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"--set {named}: " in message and "give each once" in message
    # Given once, by either route, it passes to the next check: the source must be a student.
    alone = [flag for flag in flags if flag.startswith("--set") or "=" in flag]
    if named not in ("seed", "lookahead_candidates"):
        with pytest.raises(SystemExit):
            continuation.main([str(tmp_path), str(tmp_path / "out"), "--seed", "9", *alone])
        assert "not a student written by offline.py" in capsys.readouterr().err
