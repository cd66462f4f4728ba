"""`clamgen view` under a virtual X display (Xvfb): the viewer opens on the seeded task with
the target, obstacles and camera frusta drawn, pauses, steps once on the Right arrow, resumes
on Space and closes after `--max-steps`. Screenshots come from `xwd`, keys from `xdotool`."""

from __future__ import annotations

import os
import queue
import shutil
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

TOOLS = ("Xvfb", "xwd", "xdotool")
MISSING = [tool for tool in TOOLS if shutil.which(tool) is None]
needs_x_tools = pytest.mark.skipif(
    bool(MISSING),
    reason=f"needs {', '.join(MISSING)} on PATH (Debian: apt-get install xvfb x11-apps xdotool)",
)
# Opening the viewer takes long on a busy 2-core machine (MuJoCo allocates its user scene).
OPEN_TIMEOUT_S = 300
MAX_STEPS = 12


def read_xwd(data: bytes) -> np.ndarray:
    """An XWD screenshot (ZPixmap, 24 or 32 bits per pixel, TrueColor or DirectColor) as
    (H, W, 3) uint8 RGB."""
    header = np.frombuffer(data[:100], ">u4")
    header_size, width, height = int(header[0]), int(header[4]), int(header[5])
    byte_order, bits_per_pixel, bytes_per_line = int(header[7]), int(header[11]), int(header[12])
    num_colors = int(header[19])
    assert int(header[2]) == 2, "not a ZPixmap"
    start = header_size + 12 * num_colors  # XWDColor entries: 12 bytes each
    rows = np.frombuffer(data[start : start + height * bytes_per_line], np.uint8)
    pixels = rows.reshape(height, bytes_per_line)[:, : width * bits_per_pixel // 8]
    pixels = pixels.reshape(height, width, bits_per_pixel // 8)
    # Masks are red 0xff0000, green 0xff00, blue 0xff: LSB-first bytes are B, G, R.
    return pixels[..., [2, 1, 0]] if byte_order == 0 else pixels[..., -3:]


def count_colour(image: np.ndarray, rgb, tolerance: int = 40) -> int:
    return int((np.abs(image.astype(int) - np.array(rgb)).max(axis=-1) <= tolerance).sum())


@pytest.fixture
def display():
    read_end, write_end = os.pipe()
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write_end), "-screen", "0", "1280x960x24", "-nolisten", "tcp"],
        pass_fds=(write_end,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(write_end)
    with os.fdopen(read_end) as pipe:
        number = pipe.readline().strip()
    assert number, "Xvfb did not report its display"
    try:
        yield f":{number}"
    finally:
        server.terminate()
        server.wait(timeout=30)


def _lines(process: subprocess.Popen) -> queue.Queue:
    lines: queue.Queue = queue.Queue()

    def pump() -> None:
        for line in process.stdout:
            lines.put(line.rstrip("\n"))

    threading.Thread(target=pump, daemon=True).start()
    return lines


def _wait_for(lines: queue.Queue, seen: list[str], prefix: str, timeout_s: float) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=1.0)
        except queue.Empty:
            continue
        seen.append(line)
        if line.startswith(prefix):
            return line
    raise AssertionError(f"no line starting {prefix!r} within {timeout_s} s; output: {seen}")


@needs_x_tools
@pytest.mark.timeout(OPEN_TIMEOUT_S + 300)
def test_view_shows_the_task_pauses_steps_and_stops(display):
    from clamgen.experiments.viewer import OTHER_CAMERA_RGBA
    from clamgen.sim.constants import NUM_CAMERAS

    env = {**os.environ, "DISPLAY": display, "MUJOCO_GL": "egl"}
    command = [
        *(sys.executable, "-m", "clamgen.cli", "view", "--policy", "ik"),
        *("--seed", "1000000000", "--num-episodes", "5", "--paused"),
        *("--max-steps", str(MAX_STEPS), "--seconds", str(OPEN_TIMEOUT_S)),
    ]
    process = subprocess.Popen(
        command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    seen: list[str] = []
    try:
        lines = _lines(process)
        _wait_for(lines, seen, "viewer open", OPEN_TIMEOUT_S)

        # Paused on the first task: poll screenshots until the window has drawn it (the first
        # frames of a software-GL window can lag the sync).
        violet = tuple(round(255 * c) for c in OTHER_CAMERA_RGBA[:3])
        counts: dict[str, int] = {}
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            shot = subprocess.run(
                ["xwd", "-root", "-silent", "-display", display], capture_output=True, check=True
            )
            image = read_xwd(shot.stdout)
            counts = {
                "target (red)": count_colour(image, (230, 13, 13), 60),
                "obstacles (green)": count_colour(image, (26, 179, 51), 60),
                "frusta (violet)": count_colour(image, violet),
            }
            if all(counts.values()):
                break
            time.sleep(2.0)
        assert image.std() > 10, "the screenshot is blank"
        assert all(counts.values()), f"missing from the screenshot: {counts}"
        # Every camera's frustum is 8 line segments of a few pixels' width.
        assert counts["frusta (violet)"] > 200 * NUM_CAMERAS, counts

        # The only window on the display has the keyboard focus.
        subprocess.run(["xdotool", "key", "Right"], env=env, check=True)
        step = _wait_for(lines, seen, "step ", 60)
        assert step.startswith("step 1:"), step
        time.sleep(2.0)  # still paused: no further steps come
        assert lines.empty(), f"stepped while paused: {lines.get()}"
        subprocess.run(["xdotool", "key", "space"], env=env, check=True)
        closed = _wait_for(lines, seen, "viewer closed", 120)
        assert closed == f"viewer closed ({MAX_STEPS} steps) after {MAX_STEPS} steps"
        assert process.wait(timeout=60) == 0
        assert any(line.startswith("episode 0 (seed 1000000000): ") for line in seen), seen
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def test_view_without_a_display_says_how_to_get_one(monkeypatch):
    from clamgen.experiments.viewer import check_display

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ValueError, match="xvfb-run"):
        check_display()
