"""Re-render relabelled episodes so their images show the target at the new goal.

Hindsight relabelling (``clamgen.replay.her``) rewrites ``desired_goal``, but an image policy
reads the goal from its images: the red target sphere must be drawn where the relabelled goal
is, or the relabelled transitions teach the policy to reach a goal it cannot see. So, as the
paper does (section "Reversed Vision-Based Hindsight Experience Replay": "the images of the
relabelled trajectory are re-rendered in simulation"), every observation of a relabelled episode
is rendered again from its joints, the obstacles of its task and its new goal.

Rendering an episode of 100 steps costs far more than a learner update on a CPU, so
:class:`RerenderWorker` does it in a background process with its own scene and GL context, and
the learner collects finished episodes without waiting. Only joints, goals and obstacle arrays
travel to that process (a few kilobytes per episode); the episode's other arrays stay here and
the new images come back.
"""

from __future__ import annotations

import dataclasses
import itertools
import multiprocessing
import queue
import signal
import threading
import time
import traceback
from collections import deque
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from clamgen.replay.episode import DESIRED_GOAL, Episode
from clamgen.robot import ur5
from clamgen.sim import constants as C
from clamgen.sim.render import DEPTH_NOISE_STREAM, MultiViewRenderer, add_depth_noise
from clamgen.sim.scene import Obstacles, Scene
from clamgen.sim.state import SimState, images_from_render

IMAGES_KEY = "images"
"""Observation key of the camera images, (T + 1, V, 4, H, W) uint8 RGBD."""
JOINTS_KEY = "observation"
"""Observation key of the joint angles, (T + 1, 6) radians; envs record it in obs_mode="both"."""
IMAGE_CHANNELS = 4
"""RGB + depth, as ``clamgen.sim.state.images_from_render`` stacks them."""

DEFAULT_MAX_PENDING = 8
"""Episodes in flight before :meth:`RerenderWorker.submit` blocks. At 3 views x 128 px x 101
observations an episode's images are 20 MB, so this bounds the worker's backlog to ~160 MB."""
PARENT_CHECK_S = 1.0
"""How often an idle worker checks that its parent still lives (it exits when it does not)."""
CLOSE_TIMEOUT_S = 5.0
"""How long :meth:`RerenderWorker.close` waits for the worker to stop before terminating it."""
_POLL_INTERVAL_S = 0.05  # how long blocking waits sleep between liveness checks

# Messages from the worker: (kind, job id or None, payload).
_DONE = "done"  # payload: (images (T + 1, V, 4, H, W) uint8, render seconds)
_JOB_ERROR = "error"  # payload: the traceback text of one failed job; the worker goes on
_FATAL = "fatal"  # payload: the traceback text of a failure that stopped the worker


class RerenderError(RuntimeError):
    """Re-rendering failed: one episode's job (``tag`` is its tag) or the whole worker (the
    worker died; ``tag`` is None). The message carries the worker's exception text."""

    def __init__(self, message: str, tag: Any = None) -> None:
        super().__init__(message)
        self.tag = tag


# --------------------------------------------------------------------------- pure functions
def _check_inputs(joints: np.ndarray, goals: np.ndarray, obstacles: Obstacles) -> None:
    """Raise ValueError unless joints (T+1, 6), goals (T+1, 3) and the obstacle arrays agree.

    Only shapes, finiteness and kinds are checked here; how many obstacles fit is the scene's
    business (``Scene.set_obstacles`` raises).
    """
    if joints.ndim != 2 or joints.shape[1] != ur5.NUM_JOINTS or len(joints) < 1:
        raise ValueError(f"joints must be (T + 1, {ur5.NUM_JOINTS}), got {joints.shape}")
    if goals.shape != (len(joints), 3):
        raise ValueError(f"goals must be (T + 1, 3) = ({len(joints)}, 3), got {goals.shape}")
    if not (np.all(np.isfinite(joints)) and np.all(np.isfinite(goals))):
        raise ValueError("joints and goals must be finite")
    kinds = np.asarray(obstacles.kinds)
    num = len(kinds)
    if kinds.shape != (num,):
        raise ValueError(f"obstacle kinds must be (N,), got {kinds.shape}")
    for name in ("positions_m", "half_sizes_m"):
        shape = np.shape(getattr(obstacles, name))
        if shape != (num, 3):
            raise ValueError(f"obstacles.{name} must be (N, 3) = ({num}, 3), got {shape}")
    if not np.isin(kinds, (C.OBSTACLE_BOX, C.OBSTACLE_CYLINDER)).all():
        raise ValueError(f"obstacle kinds must be OBSTACLE_BOX or OBSTACLE_CYLINDER, got {kinds}")


def rerender_images(
    scene: Scene,
    renderer: MultiViewRenderer,
    joints: np.ndarray,
    goals: np.ndarray,
    obstacles: Obstacles,
    depth_noise_m: float = 0.0,
    noise_rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Images of every step of an episode with the target drawn at that step's goal.

    Args:
        scene: the scene to pose; its joints, target and obstacles are restored afterwards,
            also when rendering fails.
        renderer: renders ``scene.model``; its cameras and size set V, H and W.
        joints: (T + 1, 6) joint angles, radians.
        goals: (T + 1, 3) target centre per step, world frame, metres.
        obstacles: the episode's obstacles (they never move during an episode).
        depth_noise_m, noise_rng: the depth camera's noise (`add_depth_noise`, as
            `ReachEnv(depth_noise_m=...)` adds it), drawn from `noise_rng`; 0: exact depth.

    Returns:
        (T + 1, V, 4, H, W) uint8 RGB + depth (``clamgen.sim.state.images_from_render``), the
        same frames ``ReachEnv.render_images(joints[t], goals[t], obstacles)`` gives.
    """
    if depth_noise_m and noise_rng is None:
        raise ValueError("depth_noise_m > 0 needs a noise_rng to draw the noise from")
    joints = np.asarray(joints)
    goals = np.asarray(goals)
    _check_inputs(joints, goals, obstacles)
    images = np.empty(
        (len(joints), renderer.num_views, IMAGE_CHANNELS, renderer.height, renderer.width),
        np.uint8,
    )
    saved = SimState.capture(scene)
    try:
        # Obstacles are fixed for the episode: place them once, not once per frame.
        scene.set_obstacles(obstacles)
        for t, (q, goal) in enumerate(zip(joints, goals, strict=True)):
            scene.data.mocap_pos[scene.target_mocap] = goal
            scene.set_joints(q)  # mj_kinematics also moves the mocap target body
            rgb, depth_m = renderer.render(scene.data)
            images[t] = images_from_render(rgb, add_depth_noise(depth_m, depth_noise_m, noise_rng))
    finally:
        saved.apply(scene)
    return images


def _episode_inputs(
    episode: Episode, obstacles: Obstacles, view_shape: tuple[int, int, int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Joints (T+1, 6) and goals (T+1, 3) of ``episode``, checked against the renderer's
    per-observation image shape ``view_shape`` = (V, 4, H, W) when the episode has images."""
    if JOINTS_KEY not in episode.obs:
        raise ValueError(
            f"the episode has no {JOINTS_KEY!r} key: re-rendering needs the joint angles of "
            f"every step (record the episode with obs_mode='both')"
        )
    joints = np.asarray(episode.obs[JOINTS_KEY])
    goals = np.asarray(episode.obs[DESIRED_GOAL])
    _check_inputs(joints, goals, obstacles)
    if IMAGES_KEY in episode.obs:
        # Replacing images of another shape would silently change the observation space.
        shape = np.shape(episode.obs[IMAGES_KEY])
        expected = (len(joints), *view_shape)
        if shape != expected:
            raise ValueError(
                f"the episode's images are {shape} but the renderer makes {expected} "
                f"(T + 1, V, 4, H, W): check num_views and image_size"
            )
    return joints, goals


def _with_images(episode: Episode, images: np.ndarray) -> Episode:
    return dataclasses.replace(episode, obs={**episode.obs, IMAGES_KEY: images})


def rerender_episode(
    episode: Episode, obstacles: Obstacles, scene: Scene, renderer: MultiViewRenderer
) -> Episode:
    """``episode`` with ``obs["images"]`` re-rendered at its (relabelled) ``desired_goal``.

    Joints come from ``obs["observation"]`` (T + 1, 6), goals from ``obs["desired_goal"]``
    (T + 1, 3); every other array is the input's (not copied). An episode without images gets
    them. Raises ValueError when the joints are missing or the episode's images have another
    shape than the renderer makes.
    """
    view_shape = (renderer.num_views, IMAGE_CHANNELS, renderer.height, renderer.width)
    joints, goals = _episode_inputs(episode, obstacles, view_shape)
    return _with_images(episode, rerender_images(scene, renderer, joints, goals, obstacles))


def _make_renderer(scene: Scene, num_views: int, image_size: int) -> MultiViewRenderer:
    return MultiViewRenderer(scene.model, scene.camera_ids[:num_views], image_size, image_size)


def _noise_rng(seed: int, job_id: int) -> np.random.Generator:
    """The depth noise's stream for one job: fixed by the worker's seed and the job's number,
    so that the same submissions get the same noise in the worker and in this process."""
    return np.random.default_rng([seed, DEPTH_NOISE_STREAM, job_id])


# ------------------------------------------------------------------------ worker process
class _Sender:
    """Sends a worker's messages from a thread, so rendering goes on while the parent has not
    yet read the last episode's images (a pipe holds only ~64 kB)."""

    def __init__(self, connection: Connection) -> None:
        self._connection = connection
        self._outbox: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="rerender-sender", daemon=True)
        self._thread.start()

    def send(self, message: tuple[str, int | None, Any]) -> None:
        self._outbox.put(message)

    def close(self) -> None:
        """Send what is queued (waits for the parent to read it), then close the pipe."""
        self._outbox.put(None)
        self._thread.join()
        self._connection.close()

    def _run(self) -> None:
        while (message := self._outbox.get()) is not None:
            try:
                self._connection.send(message)
            except OSError:  # the parent is gone: nobody to send to
                return


def _worker_main(
    requests: multiprocessing.Queue,
    results: Connection,
    num_views: int,
    size: int,
    depth_noise_m: float,
    seed: int,
) -> None:
    """Body of the worker process: render jobs until the ``None`` sentinel or parent's death.

    A job is ``(job_id, joints, goals, kinds, positions_m, half_sizes_m)``. A failing job is
    reported and the worker goes on; a failure outside a job (scene, GL context) is reported as
    fatal and ends the worker with exit code 1.
    """
    # Ctrl-C reaches the whole process group; the parent decides when this worker stops.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sender = _Sender(results)
    try:
        scene = Scene()
        renderer = _make_renderer(scene, num_views, size)
        renderer.render(scene.data)  # create the GL context now, so that a failure shows at once
    except Exception:
        sender.send((_FATAL, None, traceback.format_exc()))
        sender.close()
        raise SystemExit(1) from None
    parent = multiprocessing.parent_process()
    try:
        while True:
            try:
                job = requests.get(timeout=PARENT_CHECK_S)
            except queue.Empty:
                # An orphaned worker would wait forever: leave when the parent is gone.
                if parent is not None and not parent.is_alive():
                    return
                continue
            if job is None:
                return
            job_id, joints, goals, kinds, positions_m, half_sizes_m = job
            try:
                start = time.perf_counter()
                obstacles = Obstacles(kinds, positions_m, half_sizes_m)
                images = rerender_images(
                    scene, renderer, joints, goals, obstacles, depth_noise_m,
                    _noise_rng(seed, job_id) if depth_noise_m else None,
                )  # fmt: skip
                sender.send((_DONE, job_id, (images, time.perf_counter() - start)))
            except Exception:
                sender.send((_JOB_ERROR, job_id, traceback.format_exc()))
    finally:
        renderer.close()
        sender.close()


@dataclasses.dataclass
class _Job:
    """What the parent keeps of a submitted episode: everything but its images."""

    tag: Any
    episode: Episode
    submitted_s: float


class RerenderWorker:
    """Re-renders episodes in a background process so that learning does not wait.

    The worker owns a :class:`~clamgen.sim.scene.Scene` and a
    :class:`~clamgen.sim.render.MultiViewRenderer` of the first ``num_views`` cameras at
    ``image_size`` x ``image_size`` pixels, the configuration of ``ReachEnv(num_views=...,
    image_size=...)``, so its frames equal the env's for the same joints (episodes record the
    joints as float32, ~1e-7 rad off the simulator's, which can flip an edge pixel). It is
    started with the "spawn" method: a forked child of a process that already made a GL
    context (the env's) cannot make its own. Spawn re-imports the main module, so a script
    that creates a worker needs an ``if __name__ == "__main__":`` guard.

    Usage::

        with RerenderWorker(num_views=2, image_size=128) as worker:
            for relabelled in reversible_her(episode, env.compute_reward):
                worker.submit(relabelled, env.task.obstacles)
            ...
            for tag, episode in worker.poll():  # never blocks
                buffer.add_episode(episode)

    Semantics:

    - Results come back in submission order as ``(tag, episode)``; ``tag`` never leaves this
      process, so it can be any object.
    - At most ``max_pending`` episodes are in flight. ``submit`` then *blocks* until one
      finishes (backpressure: when rendering cannot keep up, the learner slows down rather
      than memory growing without bound); with ``block=False``, or when ``timeout`` (seconds)
      runs out, it raises ``queue.Full`` instead, so a caller may drop the episode.
    - ``submit`` checks shapes at once (ValueError). A job that fails in the worker (e.g. more
      obstacles than the scene has slots) is raised by the next ``poll``/``drain`` as a
      :class:`RerenderError` carrying the worker's traceback; the worker goes on. If the
      worker dies, every later call raises :class:`RerenderError` with its exception text or
      exit code; results that had finished before are still returned first.
    - ``synchronous=True`` renders inside ``submit``, in this process (tests, platforms
      without multiprocessing); results and errors are delivered the same way.
    - ``close()`` (also on leaving a ``with`` block and on garbage collection) stops and
      reaps the process; episodes still pending are dropped, call ``drain`` first to keep them.

    Args:
        num_views: cameras to render, the first ``num_views`` of ``constants.CAMERAS`` (1..4).
        image_size: height = width of each view, pixels.
        max_pending: episodes in flight before ``submit`` blocks (>= 1).
        synchronous: render in this process inside ``submit``; no worker process.
        depth_noise_m: the depth camera's noise model (`ReachEnv(depth_noise_m=...)`), so that
            re-rendered images are as noisy as the env's; 0: exact depth.
        seed: seeds the noise: the k-th episode submitted gets the same noise in the worker and
            in synchronous mode.
    """

    def __init__(
        self,
        num_views: int,
        image_size: int,
        *,
        max_pending: int = DEFAULT_MAX_PENDING,
        synchronous: bool = False,
        depth_noise_m: float = 0.0,
        seed: int = 0,
    ) -> None:
        # Set first so that close() and __del__ work however far __init__ gets.
        self._closed = False
        self._process: Any = None
        self._renderer: MultiViewRenderer | None = None
        if not 1 <= num_views <= C.NUM_CAMERAS:
            raise ValueError(f"num_views must be in 1..{C.NUM_CAMERAS}, got {num_views}")
        if int(image_size) != image_size or image_size < 1:
            raise ValueError(f"image_size must be a positive integer, got {image_size}")
        if max_pending < 1:
            raise ValueError(f"max_pending must be >= 1, got {max_pending}")
        if not 0 <= depth_noise_m < float("inf"):
            raise ValueError(f"depth_noise_m must be a finite number >= 0, got {depth_noise_m}")
        self.num_views = num_views
        self.image_size = int(image_size)
        self.max_pending = max_pending
        self.synchronous = synchronous
        self.depth_noise_m = float(depth_noise_m)
        self.seed = int(seed)
        self._view_shape = (num_views, IMAGE_CHANNELS, self.image_size, self.image_size)
        self._job_ids = itertools.count()
        self._jobs: dict[int, _Job] = {}  # submitted, not yet back from the worker
        self._ready: list[tuple[Any, Episode]] = []
        self._errors: deque[RerenderError] = deque()
        self._fatal: str | None = None  # the worker's death notice, once known
        self._eof = False  # the worker closed its end of the result pipe
        self._num_episodes = 0
        self._num_frames = 0
        self._render_s = 0.0
        self._latency_s = 0.0
        self._scene: Scene | None = None
        if synchronous:
            return
        context = multiprocessing.get_context("spawn")
        self._requests = context.Queue()  # its feeder thread keeps submit() from blocking
        self._results, writer = context.Pipe(duplex=False)
        self._process = context.Process(
            target=_worker_main,
            args=(self._requests, writer, num_views, self.image_size, depth_noise_m, seed),
            name="clamgen-rerender",
            # Daemonic: the interpreter terminates it at exit if close() was never called.
            daemon=True,
        )
        self._process.start()
        # Only the worker may hold the writing end: then a worker that dies, even in the middle
        # of a message, ends the pipe (EOFError here) instead of leaving a read hanging.
        writer.close()

    # ------------------------------------------------------------------------ public API
    @property
    def pending(self) -> int:
        """Episodes submitted and not yet finished (finished ones wait in :meth:`poll`)."""
        return len(self._jobs)

    @property
    def pid(self) -> int | None:
        """Process id of the worker, None in synchronous mode."""
        return None if self._process is None else self._process.pid

    @property
    def stats(self) -> dict[str, float]:
        """Metrics to log. A frame is one observation's images, all V views together.

        - ``rerender/frames_per_s``: frames rendered per second of rendering in the worker
          (excludes waiting for jobs and transfer), 0 before the first episode.
        - ``rerender/latency_s``: mean seconds from ``submit`` to the episode being ready here
          (queueing + rendering + transfer).
        - ``rerender/episodes``, ``rerender/frames``: totals finished; ``rerender/pending``.
        """
        done = max(self._num_episodes, 1)
        return {
            "rerender/frames_per_s": self._num_frames / self._render_s if self._render_s else 0.0,
            "rerender/latency_s": self._latency_s / done,
            "rerender/episodes": float(self._num_episodes),
            "rerender/frames": float(self._num_frames),
            "rerender/pending": float(self.pending),
        }

    def submit(
        self,
        episode: Episode,
        obstacles: Obstacles,
        tag: Any = None,
        *,
        block: bool = True,
        timeout: float | None = None,
    ) -> None:
        """Queue ``episode`` for re-rendering at its ``desired_goal`` among ``obstacles``.

        Sends the joints (T + 1, 6), goals (T + 1, 3) and obstacle arrays only; the old images
        are neither sent nor kept. Blocks while ``max_pending`` episodes are in flight (see the
        class docstring); raises ``queue.Full`` when ``block`` is False or ``timeout`` seconds
        pass, ValueError for a malformed episode, RerenderError when the worker died.
        """
        self._check_open()
        joints, goals = _episode_inputs(episode, obstacles, self._view_shape)
        # Keep everything but the images: the result brings new ones, and holding the old ones
        # until then would double the memory of the backlog.
        rest = {key: value for key, value in episode.obs.items() if key != IMAGES_KEY}
        job = _Job(tag, dataclasses.replace(episode, obs=rest), time.perf_counter())
        if self.synchronous:
            self._render_here(job, next(self._job_ids), joints, goals, obstacles)
            return
        self._wait_for_slot(block, timeout)
        job_id = next(self._job_ids)
        self._jobs[job_id] = job
        self._requests.put(
            (
                job_id,
                np.ascontiguousarray(joints),
                np.ascontiguousarray(goals),
                np.asarray(obstacles.kinds),
                np.asarray(obstacles.positions_m),
                np.asarray(obstacles.half_sizes_m),
            )
        )

    def poll(self) -> list[tuple[Any, Episode]]:
        """Finished episodes as ``(tag, episode)`` in submission order; never blocks.

        Raises RerenderError for a job that failed (once per job; finished episodes stay for
        the next call) and, once nothing finished is left, when the worker has died.
        """
        self._check_open()
        self._receive(block=False)
        self._note_death()
        if self._errors:
            raise self._errors.popleft()
        if self._ready:
            ready, self._ready = self._ready, []
            return ready
        self._raise_if_dead()
        return []

    def drain(self, timeout: float | None = None) -> list[tuple[Any, Episode]]:
        """Wait until nothing is pending, then :meth:`poll`. Raises TimeoutError after
        ``timeout`` seconds (None: no limit); what finished stays for the next poll."""
        self._check_open()
        deadline = None if timeout is None else time.monotonic() + timeout
        while self._jobs:
            if deadline is not None and time.monotonic() >= deadline:
                raise TimeoutError(
                    f"{self.pending} episode(s) still re-rendering after {timeout} s"
                )
            self._receive(block=True)
            self._raise_if_dead()
        return self.poll()

    def close(self) -> None:
        """Stop the worker and release its resources; pending episodes are dropped. Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        process = self._process
        if process is None:
            return
        if process.is_alive():
            try:
                self._requests.put(None)
            except (OSError, ValueError):  # queue already broken: terminate below
                pass
            deadline = time.monotonic() + CLOSE_TIMEOUT_S
            while process.is_alive() and time.monotonic() < deadline:
                # The worker exits only once its sender thread has sent every result: keep
                # reading, or a full pipe would keep it alive.
                self._discard_results()
                process.join(_POLL_INTERVAL_S)
            if process.is_alive():
                process.terminate()
                process.join(1.0)
            if process.is_alive():
                process.kill()
        process.join()
        self._jobs.clear()
        # Do not let interpreter exit wait on requests the dead worker will never read.
        self._requests.cancel_join_thread()
        self._requests.close()
        self._results.close()

    def __enter__(self) -> RerenderWorker:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: modules or the process may already be gone
            pass

    # ------------------------------------------------------------------------- internals
    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("this RerenderWorker is closed")

    def _render_here(
        self, job: _Job, job_id: int, joints: np.ndarray, goals: np.ndarray, obstacles: Obstacles
    ) -> None:
        if self._scene is None:
            self._scene = Scene()
            self._renderer = _make_renderer(self._scene, self.num_views, self.image_size)
        try:
            start = time.perf_counter()
            images = rerender_images(
                self._scene, self._renderer, joints, goals, obstacles, self.depth_noise_m,
                _noise_rng(self.seed, job_id) if self.depth_noise_m else None,
            )  # fmt: skip
            render_s = time.perf_counter() - start
        except Exception as error:
            failure = RerenderError(
                f"re-rendering the episode tagged {job.tag!r} failed:\n{traceback.format_exc()}",
                job.tag,
            )
            failure.__cause__ = error
            self._errors.append(failure)
            return
        self._finish(job, images, render_s)

    def _finish(self, job: _Job, images: np.ndarray, render_s: float) -> None:
        self._ready.append((job.tag, _with_images(job.episode, images)))
        self._num_episodes += 1
        self._num_frames += len(images)
        self._render_s += render_s
        self._latency_s += time.perf_counter() - job.submitted_s

    def _handle(self, message: tuple[str, int | None, Any]) -> None:
        kind, job_id, payload = message
        if kind == _FATAL:
            self._fatal = f"the re-render worker failed:\n{payload}"
            return
        job = self._jobs.pop(job_id)
        if kind == _DONE:
            images, render_s = payload
            self._finish(job, images, render_s)
        else:
            self._errors.append(
                RerenderError(
                    f"re-rendering the episode tagged {job.tag!r} failed in the worker:\n{payload}",
                    job.tag,
                )
            )

    def _receive(self, block: bool) -> None:
        """Move every message that has arrived into the ready / error lists; with ``block``,
        first wait up to one poll interval for one."""
        if self._process is None or self._eof:
            return
        timeout = _POLL_INTERVAL_S if block else 0.0
        try:
            while self._results.poll(timeout):
                self._handle(self._results.recv())
                timeout = 0.0
        except (EOFError, OSError):  # the worker closed its end: it exited or is exiting
            self._eof = True

    def _discard_results(self) -> None:
        try:
            while self._results.poll(_POLL_INTERVAL_S):
                self._results.recv()
        except (EOFError, OSError):
            pass

    def _note_death(self) -> None:
        """Record why the worker is gone, if it is, after collecting what it sent before."""
        process = self._process
        if process is None or self._fatal is not None:
            return
        if self._eof:
            process.join(CLOSE_TIMEOUT_S)  # the pipe ends when the worker exits: reap it
        if process.is_alive():
            return
        # Whatever it sent before it died is still in the pipe.
        self._receive(block=False)
        if self._fatal is not None:  # it said why
            return
        code = process.exitcode
        how = (
            f"was killed by signal {signal.Signals(-code).name}"
            if code is not None and code < 0
            else f"exited with code {code}"
        )
        self._fatal = (
            f"the re-render worker (pid {process.pid}) {how} without reporting an error "
            "(see its stderr)"
        )

    def _raise_if_dead(self) -> None:
        """Raise RerenderError if the worker process is gone (synchronous mode never is)."""
        self._note_death()
        if self._fatal is not None:
            lost = f"; {self.pending} pending episode(s) lost" if self._jobs else ""
            raise RerenderError(self._fatal + lost)

    def _wait_for_slot(self, block: bool, timeout: float | None) -> None:
        self._receive(block=False)
        self._raise_if_dead()
        deadline = None if timeout is None else time.monotonic() + timeout
        while len(self._jobs) >= self.max_pending:
            if not block or (deadline is not None and time.monotonic() >= deadline):
                raise queue.Full(
                    f"{self.pending} episodes pending (max_pending={self.max_pending})"
                )
            self._receive(block=True)
            self._raise_if_dead()
