"""Multi-view RGBD observations per second: CLAMGen's renderer vs PyBullet's TinyRenderer.

Both draw the same scene (two obstacles, target, arm at the task's start) from the first three
cameras at 128x128 and return RGB uint8 plus metric depth per view.

    python benchmarks/render.py [--num-frames 100] [--views 3] [--size 128]

Prints both rates and the ratio, writes results/benchmarks/render.csv. Target: >= 2x.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import best_rate, write_csv
from pybullet_scene import PyBulletScene

import clamgen  # noqa: F401
from clamgen.envs.reach_env import ReachEnv
from clamgen.sim.render import MultiViewRenderer
from clamgen.sim.state import images_from_render


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-frames", type=int, default=100)
    parser.add_argument("--views", type=int, default=3)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument(
        "--quality", default="fast", choices=["fast", "pretty"], help="our renderer's preset"
    )
    args = parser.parse_args()

    env = ReachEnv(num_obstacles=2)
    env.reset(seed=0)
    scene = env.scene
    renderer = MultiViewRenderer(
        scene.model, scene.camera_ids[: args.views], args.size, args.size, args.quality
    )
    reference = PyBulletScene()
    reference.set_obstacles(scene.obstacles)
    reference.set_joints(scene.joints)
    reference.set_target(scene.target_position)

    def ours():
        for _ in range(args.num_frames):
            images_from_render(*renderer.render(scene.data))

    def theirs():
        for _ in range(args.num_frames):
            reference.camera_images(args.size, args.size, args.views)

    ours()  # warm-up: GL context and shader compilation
    rate_ours = best_rate(ours, args.num_frames)
    rate_theirs = best_rate(theirs, args.num_frames)
    ratio = rate_ours / rate_theirs
    what = f"{args.views}-view {args.size}x{args.size} RGBD observations/s"
    print(f"{what}:")
    print(f"  CLAMGen (MuJoCo, one GL context)  {rate_ours:8.1f}")
    print(f"  PyBullet TinyRenderer             {rate_theirs:8.1f}")
    print(f"  ratio {ratio:.2f}x (target >= 2x)")
    path = write_csv(
        "render" if args.quality == "fast" else f"render_{args.quality}",
        [
            {
                "benchmark": f"render_{args.views}view_{args.size}px_{args.quality}",
                "clamgen_per_s": round(rate_ours, 1),
                "pybullet_per_s": round(rate_theirs, 1),
                "ratio": round(ratio, 2),
                "num_frames": args.num_frames,
            }
        ],
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
