"""Re-rendering relabelled episodes: the target moves to the new goal, frames match the env's,
and the background worker agrees with in-process rendering, reports errors and shuts down."""

from __future__ import annotations

import dataclasses
import gc
import multiprocessing
import os
import queue
import signal
import time

import numpy as np
import pytest

import clamgen  # noqa: F401  (sets MUJOCO_GL before mujoco is imported)
from clamgen.envs.reach_env import ReachEnv
from clamgen.replay.episode import Episode, EpisodeRecorder
from clamgen.replay.her import reversible_her
from clamgen.replay.rerender import (
    RerenderError,
    RerenderWorker,
    rerender_episode,
    rerender_images,
)
from clamgen.sim import constants as C
from clamgen.sim.render import MultiViewRenderer, project_points
from clamgen.sim.scene import Obstacles, Scene

NUM_VIEWS = 2
IMAGE_SIZE = 32
NUM_STEPS = 8
WORKER_TIMEOUT_S = 30.0


@dataclasses.dataclass(frozen=True)
class Rollout:
    env: ReachEnv
    episode: Episode
    obstacles: Obstacles
    joints_f64: np.ndarray
    """(T + 1, 6) the simulator's joints; the episode stores them rounded to float32."""


@pytest.fixture(scope="module")
def rollout() -> Rollout:
    env = ReachEnv(num_obstacles=2, num_views=NUM_VIEWS, image_size=IMAGE_SIZE, obs_mode="both")
    obs, _ = env.reset(seed=0)
    recorder = EpisodeRecorder(obs)
    joints = [env.scene.joints]
    rng = np.random.default_rng(0)
    for _ in range(NUM_STEPS):
        action = rng.uniform(-1.0, 1.0, 6).astype(np.float32)
        obs, _, terminated, truncated, info = env.step(action)
        recorder.add(action, obs, info)
        joints.append(env.scene.joints)
        assert not (terminated or truncated)
    yield Rollout(env, recorder.episode(), env.task.obstacles, np.array(joints))
    env.close()


@pytest.fixture(scope="module")
def scene_and_renderer():
    scene = Scene()
    renderer = MultiViewRenderer(scene.model, scene.camera_ids[:NUM_VIEWS], IMAGE_SIZE, IMAGE_SIZE)
    yield scene, renderer
    renderer.close()


@pytest.fixture(scope="module")
def worker():
    with RerenderWorker(NUM_VIEWS, IMAGE_SIZE) as worker:
        yield worker


def relabelled(rollout: Rollout) -> tuple[Episode, ...]:
    episodes = reversible_her(rollout.episode, rollout.env.compute_reward)
    assert len(episodes) == 2  # the random rollout fails, so it is relabelled
    return episodes


def with_goal(episode: Episode, goal) -> Episode:
    goals = np.broadcast_to(np.float32(goal), episode.obs["desired_goal"].shape).copy()
    return dataclasses.replace(episode, obs={**episode.obs, "desired_goal": goals})


def red_mask(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels of the red target in one view's (4, H, W) RGBD image."""
    r, g, b = image[:3].astype(int)
    return (r > 150) & (g < 80) & (b < 80)


def assert_process_gone(pid: int) -> None:
    assert pid not in [child.pid for child in multiprocessing.active_children()]
    with pytest.raises(ProcessLookupError):  # reaped, not a zombie
        os.kill(pid, 0)


# ------------------------------------------------------------------------ pure functions
def test_frames_equal_env_render_images_and_scene_is_restored(rollout, scene_and_renderer):
    scene, renderer = scene_and_renderer
    forward, backward = relabelled(rollout)
    scene.set_joints(np.full(6, 0.3))
    scene.set_target(np.array([0.5, 0.1, 0.2]))
    before = scene.joints, scene.target_position, scene.obstacles
    for episode in (forward, backward):
        joints, goals = episode.obs["observation"], episode.obs["desired_goal"]
        images = rerender_images(scene, renderer, joints, goals, rollout.obstacles)
        assert images.shape == (len(joints), NUM_VIEWS, 4, IMAGE_SIZE, IMAGE_SIZE)
        assert images.dtype == np.uint8
        expected = np.stack(
            [
                rollout.env.render_images(q, g, rollout.obstacles)
                for q, g in zip(joints, goals, strict=True)
            ]
        )
        np.testing.assert_array_equal(images, expected)
    np.testing.assert_array_equal(scene.joints, before[0])
    np.testing.assert_array_equal(scene.target_position, before[1])
    assert scene.obstacles is before[2]


def test_original_episode_rerenders_to_its_stored_images(rollout, scene_and_renderer):
    scene, renderer = scene_and_renderer
    episode = rollout.episode
    # With the simulator's own joints the pipeline reproduces the env's frames bit for bit.
    exact = dataclasses.replace(episode, obs={**episode.obs, "observation": rollout.joints_f64})
    rerendered = rerender_episode(exact, rollout.obstacles, scene, renderer)
    np.testing.assert_array_equal(rerendered.obs["images"], episode.obs["images"])
    # The recorded observation holds the joints rounded to float32 (~1e-7 rad): at most an
    # edge pixel may flip.
    rerendered = rerender_episode(episode, rollout.obstacles, scene, renderer)
    differs = rerendered.obs["images"] != episode.obs["images"]
    assert differs.mean() < 1e-3


def test_target_is_drawn_at_the_new_goal(rollout, scene_and_renderer):
    scene, _ = scene_and_renderer
    # At 32 px the 2 cm target covers about one pixel; at 96 px its centroid is measurable.
    size = 96
    renderer = MultiViewRenderer(scene.model, scene.camera_ids[:NUM_VIEWS], size, size)
    episode = dataclasses.replace(
        rollout.episode, obs={k: v for k, v in rollout.episode.obs.items() if k != "images"}
    )
    old_goal = episode.obs["desired_goal"][0]
    new_goal = np.array([0.6, -0.2, 0.1])
    cameras = scene.camera_ids[:NUM_VIEWS]
    pixels = {
        name: [project_points(scene.model, scene.data, cam, goal, size, size) for cam in cameras]
        for name, goal in (("old", old_goal), ("new", new_goal))
    }
    for old, new in zip(pixels["old"], pixels["new"], strict=True):
        assert np.hypot(*(new - old)) > 10  # the goal moves visibly in every view
    for name, goal in (("old", old_goal), ("new", new_goal)):
        images = rerender_episode(with_goal(episode, goal), rollout.obstacles, scene, renderer)
        visible = 0
        for t in range(episode.num_steps + 1):
            for view in range(NUM_VIEWS):
                red = np.argwhere(red_mask(images.obs["images"][t, view]))
                if len(red) == 0:  # hidden behind the arm or an obstacle
                    continue
                visible += 1
                # Pixel (r, c) covers [r, r + 1) x [c, c + 1): compare its centre (col, row).
                centres = red[:, ::-1] + 0.5
                offsets = np.linalg.norm(centres - pixels[name][view], axis=1)
                assert offsets.max() < 4.0, (name, t, view)  # red only around this goal
                assert np.linalg.norm(centres.mean(axis=0) - pixels[name][view]) < 1.5
        assert visible >= episode.num_steps  # seen at most steps in at least one view
    renderer.close()


def test_rerender_episode_changes_only_the_images(rollout, scene_and_renderer):
    scene, renderer = scene_and_renderer
    forward, _ = relabelled(rollout)
    rerendered = rerender_episode(forward, rollout.obstacles, scene, renderer)
    assert not np.array_equal(rerendered.obs["images"], forward.obs["images"])  # stale before
    assert rerendered.obs.keys() == forward.obs.keys()
    for key, value in forward.obs.items():
        if key != "images":
            assert rerendered.obs[key] is value
    for name in ("actions", "executed_actions", "collisions", "successes"):
        assert getattr(rerendered, name) is getattr(forward, name)


def test_malformed_inputs_are_rejected(rollout, scene_and_renderer):
    scene, renderer = scene_and_renderer
    episode = rollout.episode
    no_joints = dataclasses.replace(
        episode, obs={k: v for k, v in episode.obs.items() if k != "observation"}
    )
    with pytest.raises(ValueError, match="'observation'"):
        rerender_episode(no_joints, rollout.obstacles, scene, renderer)
    wide = MultiViewRenderer(scene.model, scene.camera_ids[:3], IMAGE_SIZE, IMAGE_SIZE)
    with pytest.raises(ValueError, match="num_views and image_size"):
        rerender_episode(episode, rollout.obstacles, scene, wide)
    with pytest.raises(ValueError, match="goals"):
        rerender_images(scene, renderer, np.zeros((3, 6)), np.zeros((2, 3)), rollout.obstacles)


# ----------------------------------------------------------------------------- the worker
def test_worker_frames_equal_synchronous_frames(rollout, worker):
    episodes = (*relabelled(rollout), rollout.episode)
    with RerenderWorker(NUM_VIEWS, IMAGE_SIZE, synchronous=True) as local:
        assert local.pid is None
        for i, episode in enumerate(episodes):
            local.submit(episode, rollout.obstacles, tag=("local", i))
            worker.submit(episode, rollout.obstacles, tag=("worker", i))
        assert local.pending == 0
        expected = local.poll()
    results = worker.drain(timeout=WORKER_TIMEOUT_S)
    assert worker.pending == 0
    assert [tag for tag, _ in results] == [("worker", i) for i in range(len(episodes))]
    for (_, got), (_, want), episode in zip(results, expected, episodes, strict=True):
        np.testing.assert_array_equal(got.obs["images"], want.obs["images"])
        np.testing.assert_array_equal(got.obs["desired_goal"], episode.obs["desired_goal"])
        np.testing.assert_array_equal(got.actions, episode.actions)
    stats = worker.stats
    assert stats["rerender/episodes"] == len(episodes)
    assert stats["rerender/frames"] == sum(e.num_steps + 1 for e in episodes)
    assert stats["rerender/frames_per_s"] > 0 and stats["rerender/pending"] == 0
    assert worker.poll() == []


def test_noisy_rerendering_is_seeded_and_matches_the_env_noise_model(rollout):
    """With `depth_noise_m` (`EnvConfig.depth_noise_m`, image HER), re-rendered depth gets the
    env's noise model; RGB stays exact; the worker and in-process rendering draw the same
    noise for the same seed, another seed other noise."""
    from clamgen.sim.render import uint8_to_depth

    noise_m = 0.01
    episodes = (*relabelled(rollout), rollout.episode)
    results = {}
    for name, seed, synchronous in (("here", 3, True), ("worker", 3, False), ("other", 4, True)):
        with RerenderWorker(
            NUM_VIEWS, IMAGE_SIZE, synchronous=synchronous, depth_noise_m=noise_m, seed=seed
        ) as renderer:
            for i, episode in enumerate(episodes):
                renderer.submit(episode, rollout.obstacles, tag=i)
            results[name] = [e.obs["images"] for _, e in renderer.drain(WORKER_TIMEOUT_S)]
    with RerenderWorker(NUM_VIEWS, IMAGE_SIZE, synchronous=True) as exact:
        for i, episode in enumerate(episodes):
            exact.submit(episode, rollout.obstacles, tag=i)
        clean = [e.obs["images"] for _, e in exact.drain(WORKER_TIMEOUT_S)]
    for here, worker, other, want in zip(*results.values(), clean, strict=True):
        np.testing.assert_array_equal(here, worker)
        assert not np.array_equal(here[:, :, 3], other[:, :, 3])
        np.testing.assert_array_equal(here[:, :, :3], want[:, :, :3])
    depth = uint8_to_depth(np.concatenate(clean)[:, :, 3])
    error = uint8_to_depth(np.concatenate(results["here"])[:, :, 3]) - depth
    inside = (depth > C.DEPTH_RANGE_M[0] + 0.1) & (depth < C.DEPTH_RANGE_M[1] - 0.3)
    scaled = error[inside] / (noise_m * depth[inside] ** 2)
    assert abs(scaled.mean()) < 0.1 and 0.9 < scaled.std() < 1.3
    with pytest.raises(ValueError, match="depth_noise_m"):
        RerenderWorker(NUM_VIEWS, IMAGE_SIZE, synchronous=True, depth_noise_m=-1.0)


def test_worker_reports_a_malformed_submission_and_goes_on(rollout, worker):
    episode = rollout.episode
    no_joints = dataclasses.replace(
        episode, obs={k: v for k, v in episode.obs.items() if k != "observation"}
    )
    with pytest.raises(ValueError, match="'observation'"):  # caught here, nothing is sent
        worker.submit(no_joints, rollout.obstacles)
    assert worker.pending == 0
    # More obstacles than the scene has slots: only the worker's scene can tell.
    num = C.MAX_OBSTACLES + 1
    too_many = Obstacles(np.zeros(num, np.int64), np.full((num, 3), 0.5), np.full((num, 3), 0.03))
    worker.submit(episode, too_many, tag="bad")
    worker.submit(episode, rollout.obstacles, tag="good")
    with pytest.raises(RerenderError, match="at most 4 obstacles") as failure:
        worker.drain(timeout=WORKER_TIMEOUT_S)
    assert failure.value.tag == "bad" and "ValueError" in str(failure.value)
    [(tag, rerendered)] = worker.poll()  # the next episode was rendered all the same
    assert tag == "good" and rerendered.obs["images"].shape == episode.obs["images"].shape


def test_synchronous_mode_reports_errors_like_the_worker(rollout):
    num = C.MAX_OBSTACLES + 1
    too_many = Obstacles(np.zeros(num, np.int64), np.full((num, 3), 0.5), np.full((num, 3), 0.03))
    with RerenderWorker(NUM_VIEWS, IMAGE_SIZE, synchronous=True) as local:
        local.submit(rollout.episode, too_many, tag="bad")
        with pytest.raises(RerenderError, match="at most 4 obstacles") as failure:
            local.poll()
        assert failure.value.tag == "bad" and isinstance(failure.value.__cause__, ValueError)
    with pytest.raises(RuntimeError, match="closed"):
        local.poll()


def test_bounded_queue_then_worker_death_is_reported_and_closing_reaps_it(rollout):
    worker = RerenderWorker(NUM_VIEWS, IMAGE_SIZE, max_pending=1)
    pid = worker.pid
    worker.submit(rollout.episode, rollout.obstacles, tag=0)
    # The worker is still starting (a second at least), so the one slot is taken.
    with pytest.raises(queue.Full):
        worker.submit(rollout.episode, rollout.obstacles, tag=1, block=False)
    worker.submit(rollout.episode, rollout.obstacles, tag=1)  # blocks until 0 is done
    assert [tag for tag, _ in worker.drain(timeout=WORKER_TIMEOUT_S)] == [0, 1]

    worker.submit(rollout.episode, rollout.obstacles, tag=2)
    os.kill(pid, signal.SIGKILL)
    with pytest.raises(RerenderError, match="killed by signal SIGKILL"):
        worker.drain(timeout=WORKER_TIMEOUT_S)
    with pytest.raises(RerenderError, match="SIGKILL"):
        worker.submit(rollout.episode, rollout.obstacles)
    worker.close()
    worker.close()  # idempotent
    assert_process_gone(pid)


def test_worker_startup_failure_carries_its_exception_text(rollout, monkeypatch):
    # The spawned worker inherits this environment: no GL backend, so no GL context.
    monkeypatch.setenv("MUJOCO_GL", "disable")
    with RerenderWorker(NUM_VIEWS, IMAGE_SIZE) as worker:
        pid = worker.pid
        worker.submit(rollout.episode, rollout.obstacles)
        with pytest.raises(RerenderError, match="could not create an OpenGL context") as failure:
            worker.drain(timeout=WORKER_TIMEOUT_S)
        assert "1 pending episode(s) lost" in str(failure.value)
    assert_process_gone(pid)


def test_close_stops_the_worker_quickly_and_garbage_collection_closes_too(rollout):
    worker = RerenderWorker(NUM_VIEWS, IMAGE_SIZE)
    pid = worker.pid
    worker.submit(rollout.episode, rollout.obstacles)
    assert len(worker.drain(timeout=WORKER_TIMEOUT_S)) == 1
    start = time.perf_counter()
    worker.close()
    assert time.perf_counter() - start < 5.0
    assert_process_gone(pid)
    with pytest.raises(RuntimeError, match="closed"):
        worker.submit(rollout.episode, rollout.obstacles)

    forgotten = RerenderWorker(NUM_VIEWS, IMAGE_SIZE)
    pid = forgotten.pid
    del forgotten
    gc.collect()
    assert_process_gone(pid)
