"""Multi-camera RGB + metric depth rendering in one OpenGL context.

All views are drawn side by side into one offscreen framebuffer and read back with a single
`mjr_readPixels`, which returns colour and depth together: one render pass per camera, one read
for all of them. Shadows, reflections, skybox and fog are off: they cost about 10x on a software
(Mesa) GL and carry no information for the policy.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np

from clamgen.sim import constants as C

_GL_HINT = (
    "MuJoCo could not create an OpenGL context for offscreen rendering (MUJOCO_GL={backend!r}). "
    "Headless machines need EGL or OSMesa: set MUJOCO_GL=egl (libEGL, e.g. Debian's "
    "libegl1 + libgl1-mesa-dri) or MUJOCO_GL=osmesa (libosmesa6). Image observations need "
    "rendering; joint-only environments (num_views=0) do not."
)


_FORK_HINT = (
    "This process was forked from one that had already created an OpenGL context; EGL/OSMesa "
    "state does not survive fork() and a new context would hang. Start worker processes with "
    "'spawn' or 'forkserver', e.g. gymnasium.vector.AsyncVectorEnv(env_fns, context='spawn')."
)
# GL contexts made in this process, and whether it was forked from a process that had some.
_num_contexts_made = 0
_forked_after_gl = False


def _after_fork_in_child() -> None:
    global _forked_after_gl
    _forked_after_gl = _forked_after_gl or _num_contexts_made > 0


os.register_at_fork(after_in_child=_after_fork_in_child)


def _gl_context_class(backend: str):
    """MuJoCo's context class for `backend` as it is set now. `mujoco.GLContext` follows
    MUJOCO_GL as it was when mujoco was first imported: a user who imported mujoco before
    clamgen (which sets MUJOCO_GL=egl by default) would otherwise get a windowed backend."""
    backend = backend.lower().strip()
    if backend == "egl":
        from mujoco.egl import GLContext
    elif backend == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        GLContext = mujoco.GLContext
    return GLContext


def make_gl_context(width: int, height: int) -> mujoco.GLContext:
    """An offscreen GL context, with a hint on how to get one when it fails."""
    global _num_contexts_made
    if _forked_after_gl:
        raise RuntimeError(_FORK_HINT)
    backend = os.environ.get("MUJOCO_GL", "")
    try:
        context = _gl_context_class(backend)(width, height)
    except Exception as error:  # MuJoCo raises various error types per backend
        raise RuntimeError(_GL_HINT.format(backend=backend)) from error
    _num_contexts_made += 1
    return context


def depth_to_uint8(depth_m: np.ndarray, depth_range_m=C.DEPTH_RANGE_M) -> np.ndarray:
    """Metric depth (any shape, metres) to uint8 over `depth_range_m`, linear, clipped."""
    near, far = depth_range_m
    scaled = (np.asarray(depth_m, np.float32) - near) * (255.0 / (far - near))
    return np.clip(scaled + 0.5, 0, 255).astype(np.uint8)


DEPTH_NOISE_STREAM = 0xDE9
"""Mixed into a seed for the depth noise's own random stream (`add_depth_noise`), so that noise
draws nothing from the streams of the tasks and the target's motion."""


def add_depth_noise(depth_m: np.ndarray, noise_m: float, rng: np.random.Generator) -> np.ndarray:
    """`depth_m` (metres, any shape) with a depth camera's axial noise: Gaussian along each
    pixel's ray, of standard deviation `noise_m * z**2` at depth z (the noise of
    structured-light and stereo RGBD cameras grows with the square of the distance; 0:
    `depth_m` itself, nothing drawn)."""
    if not noise_m:
        return depth_m
    noise = rng.standard_normal(depth_m.shape, np.float32)
    return depth_m + noise * (np.float32(noise_m) * depth_m * depth_m)


def uint8_to_depth(depth_u8: np.ndarray, depth_range_m=C.DEPTH_RANGE_M) -> np.ndarray:
    """Inverse of `depth_to_uint8` (up to quantisation of (far - near) / 255 metres)."""
    near, far = depth_range_m
    return near + depth_u8.astype(np.float32) * ((far - near) / 255.0)


# Render quality presets: (multisamples, slices and stacks of curved geoms). "fast" is for policy
# inputs: no multisampling and coarser capsules make a software-GL frame ~6x cheaper, and at
# 128x128 the difference is a pixel at most. "pretty" is MuJoCo's default, for videos.
QUALITY_PRESETS = {"fast": (0, 12, 6), "pretty": (4, 28, 16)}
MARKER_RADIUS_M = 0.006
MARKER_RGBA = np.array([1.0, 0.85, 0.1, 1.0], np.float32)


class MultiViewRenderer:
    """Renders RGB and metric depth from several cameras of one model.

    Args:
        model: the compiled model (its offscreen buffer is enlarged if needed).
        camera_ids: MuJoCo camera ids, one per view, in output order.
        height, width: image size in pixels (any size the GL implementation allows).
        quality: "fast" (policy inputs) or "pretty" (videos), see `QUALITY_PRESETS`.

    The GL context is created on first use, in the calling thread or process, so that an
    environment can be built in one process and stepped in another (vector env workers).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        camera_ids,
        height: int = 128,
        width: int = 128,
        quality: str = "fast",
    ) -> None:
        if quality not in QUALITY_PRESETS:
            raise ValueError(f"quality must be one of {sorted(QUALITY_PRESETS)}, got {quality!r}")
        self.quality = quality
        if height <= 0 or width <= 0:
            raise ValueError(f"image size must be positive, got {height}x{width}")
        self.model = model
        self.camera_ids = [int(c) for c in camera_ids]
        for cam in self.camera_ids:
            if not 0 <= cam < model.ncam:
                raise ValueError(f"camera id {cam} out of range [0, {model.ncam})")
        self.height, self.width = height, width
        self.num_views = len(self.camera_ids)
        self._context: mujoco.GLContext | None = None
        self._mjr: mujoco.MjrContext | None = None
        self._scene = mujoco.MjvScene(model, maxgeom=400)
        self._option = mujoco.MjvOption()
        # No sites, joints or frames in the images: only what a real camera would see.
        self._option.sitegroup[:] = 0
        for flag in (
            mujoco.mjtRndFlag.mjRND_SHADOW,
            mujoco.mjtRndFlag.mjRND_REFLECTION,
            mujoco.mjtRndFlag.mjRND_SKYBOX,
            mujoco.mjtRndFlag.mjRND_FOG,
            mujoco.mjtRndFlag.mjRND_HAZE,
        ):
            self._scene.flags[flag] = False
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        strip_width = width * max(1, self.num_views)
        self._rgb = np.empty((height, strip_width, 3), np.uint8)
        self._depth = np.empty((height, strip_width), np.float32)
        self._full = mujoco.MjrRect(0, 0, strip_width, height)
        self._rects = [mujoco.MjrRect(i * width, 0, width, height) for i in range(self.num_views)]
        near = model.vis.map.znear * model.stat.extent
        far = model.vis.map.zfar * model.stat.extent
        # Reversed-Z depth buffer (mjDEPTH_ZEROFAR): window depth z = near * (far - d) /
        # (d * (far - near)), so metric depth d = near * far / (z * (far - near) + near).
        self._near, self._far = near, far

    def _ensure_context(self) -> None:
        if self._mjr is not None:
            return
        strip_width = self.width * max(1, self.num_views)
        vis = self.model.vis.global_
        vis.offwidth = max(vis.offwidth, strip_width)
        vis.offheight = max(vis.offheight, self.height)
        self._context = make_gl_context(strip_width, self.height)
        self._context.make_current()
        # The quality settings are read when the context is made: set them just for this one.
        quality = self.model.vis.quality
        saved = quality.offsamples, quality.numslices, quality.numstacks
        quality.offsamples, quality.numslices, quality.numstacks = QUALITY_PRESETS[self.quality]
        try:
            self._mjr = mujoco.MjrContext(self.model, mujoco.mjtFontScale.mjFONTSCALE_100)
        except mujoco.FatalError as error:
            # Typically: mujoco was imported before MUJOCO_GL was set (clamgen sets it on import).
            backend = os.environ.get("MUJOCO_GL", "")
            raise RuntimeError(_GL_HINT.format(backend=backend)) from error
        finally:
            quality.offsamples, quality.numslices, quality.numstacks = saved
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._mjr)
        self._mjr.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR

    def render(
        self, data: mujoco.MjData, markers: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Draw every view of `data` (its frames must be current, e.g. after mj_kinematics).

        Args:
            data: the simulator data to draw.
            markers: optional (N, 3) world points drawn as small yellow spheres (e.g. the tip's
                path in videos); never used for policy observations.

        Returns:
            rgb: (V, H, W, 3) uint8.
            depth_m: (V, H, W) float32, metric distance along each camera's optical axis.
        """
        self._ensure_context()
        self._context.make_current()
        for rect, cam in zip(self._rects, self.camera_ids, strict=True):
            self._camera.fixedcamid = cam
            mujoco.mjv_updateScene(
                self.model,
                data,
                self._option,
                None,
                self._camera,
                mujoco.mjtCatBit.mjCAT_ALL,
                self._scene,
            )
            if markers is not None:
                self._add_markers(markers)
            mujoco.mjr_render(rect, self._scene, self._mjr)
        mujoco.mjr_readPixels(self._rgb, self._depth, self._full, self._mjr)
        near, far = self._near, self._far
        depth = near * far / (self._depth * (far - near) + near)
        # OpenGL rows start at the bottom; split the strip into views, top row first.
        rgb = self._rgb[::-1].reshape(self.height, self.num_views, self.width, 3)
        depth = depth[::-1].reshape(self.height, self.num_views, self.width)
        return (
            np.ascontiguousarray(rgb.transpose(1, 0, 2, 3)),
            np.ascontiguousarray(depth.transpose(1, 0, 2)),
        )

    def _add_markers(self, points: np.ndarray) -> None:
        scene = self._scene
        identity = np.eye(3).ravel()
        size = np.array([MARKER_RADIUS_M, 0.0, 0.0])
        for point in np.asarray(points, np.float64)[-(scene.maxgeom - scene.ngeom) :]:
            mujoco.mjv_initGeom(
                scene.geoms[scene.ngeom],
                mujoco.mjtGeom.mjGEOM_SPHERE,
                size,
                point,
                identity,
                MARKER_RGBA,
            )
            scene.ngeom += 1

    def close(self) -> None:
        """Free the GL resources (safe to call twice)."""
        if self._mjr is not None:
            self._context.make_current()
            self._mjr.free()
            self._mjr = None
        if self._context is not None:
            self._context.free()
            self._context = None

    def __getstate__(self) -> dict:
        """What rebuilds this renderer: model, cameras, image size and quality.

        The GL context and MuJoCo's visualisation structs hold C pointers and belong to the
        thread that made them, so a pickled or deep-copied renderer makes its own context on
        its first `render` (as a new one does). Pickled with the env, `model` stays the env's
        own model object, so obstacles set on the copy's scene show in the copy's images.
        """
        return {
            "model": self.model,
            "camera_ids": self.camera_ids,
            "height": self.height,
            "width": self.width,
            "quality": self.quality,
        }

    def __setstate__(self, state: dict) -> None:
        self.__init__(**state)

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: GL may already be gone
            pass


def camera_intrinsics(model: mujoco.MjModel, camera_id: int, height: int, width: int):
    """Pinhole intrinsics (fx, fy, cx, cy) in pixels of a MuJoCo camera for an image size."""
    fovy = np.deg2rad(model.cam_fovy[camera_id])
    fy = 0.5 * height / np.tan(0.5 * fovy)
    return fy, fy, 0.5 * width, 0.5 * height


def project_points(
    model: mujoco.MjModel, data: mujoco.MjData, camera_id: int, points_m, height: int, width: int
) -> np.ndarray:
    """Pixel coordinates (..., 2) as (column, row), row 0 at the top, of world points (..., 3)."""
    points = np.asarray(points_m, np.float64)
    rotation = data.cam_xmat[camera_id].reshape(3, 3)  # columns: camera x, y, z in world
    local = (points - data.cam_xpos[camera_id]) @ rotation
    fx, fy, cx, cy = camera_intrinsics(model, camera_id, height, width)
    depth = -local[..., 2]  # the camera looks along its -z axis
    col = cx + fx * local[..., 0] / depth
    row = cy - fy * local[..., 1] / depth
    return np.stack([col, row], axis=-1)
