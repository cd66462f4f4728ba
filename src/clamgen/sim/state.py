"""Save, restore and re-render simulator states (what hindsight relabelling needs).

A `SimState` is everything that determines what the cameras see and what collides: the arm's
joints, the target's position and the obstacles. Applying it needs no stepping.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clamgen.sim.render import MultiViewRenderer, depth_to_uint8
from clamgen.sim.scene import Obstacles, Scene


@dataclass(frozen=True)
class SimState:
    """joints: (6,) radians; target_position_m: (3,) world frame; obstacles: the task's set."""

    joints: np.ndarray
    target_position_m: np.ndarray
    obstacles: Obstacles

    @staticmethod
    def capture(scene: Scene) -> SimState:
        return SimState(scene.joints, scene.target_position, scene.obstacles)

    def apply(self, scene: Scene) -> None:
        scene.set_obstacles(self.obstacles)
        scene.data.mocap_pos[scene.target_mocap] = self.target_position_m
        scene.set_joints(self.joints)


def images_from_render(rgb: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """(V, H, W, 3) uint8 RGB + (V, H, W) metric depth -> (V, 4, H, W) uint8 RGBD."""
    return np.concatenate([rgb.transpose(0, 3, 1, 2), depth_to_uint8(depth_m)[:, None]], axis=1)


def render_state(scene: Scene, renderer: MultiViewRenderer, state: SimState) -> np.ndarray:
    """Images (V, 4, H, W) uint8 of `state`, leaving the scene as it was."""
    saved = SimState.capture(scene)
    state.apply(scene)
    images = images_from_render(*renderer.render(scene.data))
    saved.apply(scene)
    return images
