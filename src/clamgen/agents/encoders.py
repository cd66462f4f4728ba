"""Multi-view image encoder of stage 2 (paper, "Learned 3D fusion for Obstacle-Avoidance").

Each camera view goes through 4 convolutional layers (ReLU); the flattened features of all views
are concatenated and passed through two dense layers to the visual encoding. Joint angles and
goal go through one dense layer + ReLU (:class:`LowDimEncoder`); :func:`fuse` concatenates the
two encodings for the controller (actor / critic) layers.

As in CURL and DrQ (Srinivas et al., 2020; Yarats et al., 2021) the visual encoding ends in
LayerNorm + tanh (``EncoderConfig.output_layer_norm``): it bounds the features that the critic,
the actor and the bilinear contrastive heads see, which those papers found to stabilise learning
from pixels. The paper only says "two dense layers", so this is our choice.

View dropout (paper, after Akinola et al., 2020): a ``view_mask`` (B, V) bool, True = kept,
zeroes the conv features of dropped views before the dense layers. By default the mask itself is
appended to the merged features (``view_mask_indicator``), so the first dense layer can tell a
dropped view from a dark one and learn a bias per dropout pattern; the kept views are not
rescaled (``rescale_kept_views``), so every view's features have the same scale in training and
at evaluation, where all views are present. :func:`view_dropout_mask` draws the masks.

The first dense layer is stored per view, ``W = [W_1 ... W_V]`` with ``W @ concat(f_1..f_V) =
sum_v W_v f_v``, which is exactly a dense layer on the concatenation but also gives, at almost no
cost, the encoding of each view alone (:meth:`MultiViewEncoder.single_view_encodings`, the
across-view contrastive term's embeddings).
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from clamgen.agents.networks import run_layers

__all__ = [
    "EncoderConfig",
    "LowDimEncoder",
    "MultiViewEncoder",
    "SpatialSoftmax",
    "bf16_enabled",
    "conv_output_size",
    "cpu_bf16_unit",
    "fuse",
    "native_bf16",
    "to_unit_float",
    "view_dropout_mask",
]

SPARSE_MAX_DENSITY = 0.5
"""`MultiViewEncoder.project_nonzero` gathers a view's weight rows only when at most this
fraction of its features is nonzero (above it, reading every row is cheaper than copying)."""
EMULATED_BF16_ENV = "CLAMGEN_EMULATED_BF16"
"""Set to 1 to run `EncoderConfig.bf16_autocast` also on CPUs that emulate bf16 (slower; closer
to the numbers of machines that compute it in hardware)."""


@functools.cache
def native_bf16(device_type: str) -> bool:
    """Whether `device_type` ("cpu", "cuda", ...) computes bf16 convs in hardware: CUDA GPUs
    that support bf16, x86 CPUs with AVX-512 BF16 or AMX. Other CPUs (AVX2 only, for one)
    emulate bf16 in oneDNN: there the shipped 3-view policy acted in 2.4 ms a step under bf16
    autocast against 1.0 ms in float32 (1 thread, AVX2; `results/stage2/precision/`)."""
    if device_type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    if device_type == "cpu":
        return bool(cpu_bf16_unit())
    return False


def cpu_bf16_unit() -> str:
    """Which unit of this CPU computes bf16: "AMX" (matrix tiles), "AVX-512 BF16, no AMX", or
    "" where neither does (:func:`native_bf16` is False there)."""
    if getattr(torch.cpu, "_is_amx_tile_supported", lambda: False)():
        return "AMX"
    if getattr(torch.cpu, "_is_avx512_bf16_supported", lambda: False)():
        return "AVX-512 BF16, no AMX"
    return ""


def bf16_enabled(device_type: str) -> bool:
    """Whether `EncoderConfig.bf16_autocast` takes effect on `device_type`: where it computes
    bf16 in hardware (:func:`native_bf16`), or anywhere with `CLAMGEN_EMULATED_BF16=1`."""
    return native_bf16(device_type) or os.environ.get(EMULATED_BF16_ENV) == "1"


@dataclass(frozen=True)
class EncoderConfig:
    """Multi-view RGBD encoder settings. Defaults are paper-like (CURL's 84 px, stride 2 then 1)."""

    image_size: int = 84
    """Side H = W in pixels of the (square, already cropped) images the encoder sees."""
    num_views: int = 3
    """Number V of camera views in each observation."""
    in_channels: int = 4
    """Channels per view: RGB + depth."""
    num_channels: int = 32
    """Output channels of every conv layer."""
    strides: tuple[int, ...] = (2, 1, 1, 1)
    """Stride of each conv layer; one entry per layer (the paper uses 4). (2, 2, 1, 1) has about
    1/8 of the conv cost of (2, 1, 1, 1) at 84 px and suits a CPU."""
    kernel_size: int = 3
    """Square kernel side of every conv layer; no padding."""
    hidden_dim: int = 256
    """Width of the first of the two dense layers that merge the views."""
    feature_dim: int = 50
    """Size of the visual encoding (CURL's 50)."""
    share_view_weights: bool = True
    """One conv stack for all views (True) or one stack per view (False). The first dense layer
    is always per view: it reads the concatenation of the views' features."""
    output_layer_norm: bool = True
    """End the visual encoding with LayerNorm + tanh (CURL / DrQ); otherwise it is linear."""
    view_mask_indicator: bool = True
    """Append the view mask (V floats, 1 = kept) to the merged features."""
    rescale_kept_views: bool = False
    """Scale the kept views' features by V / (number kept), like inverted dropout."""
    cpu_conv_chunk: int | None = None
    """On a CPU, run the convs on chunks of this many images, so the activations stay in the
    caches. With the NCHW layout (`channels_last=False`) chunks of 32 measured 1.5-2.5x
    faster forward + backward than one call on B * V images (1 thread, 64-84 px); with
    channels-last, one call measured faster. Ignored on other devices; None = one call."""
    channels_last: bool = True
    """Run the convs on channels-last (NHWC) tensors: oneDNN's faster layout on CPUs (measured
    1.6-1.9x on forward + backward here, 1 thread, 56 px, 16 channels). Same maths, up to float
    rounding."""
    bf16_autocast: bool = False
    """Run the conv layers under bf16 autocast where the device computes bf16 in hardware
    (:func:`native_bf16`: GPUs, CPUs with AVX-512 BF16 / AMX); their output features are cast
    back to float32, so everything after the convs (dense layers, losses, Q-values) stays in
    float32. Changes the numbers slightly; off = float32 throughout. On other CPUs the convs
    run in float32 regardless (emulated bf16 is slower there, and no closer to the hardware's
    numbers than float32 is to either; `CLAMGEN_EMULATED_BF16=1` runs it anyway)."""
    low_dim_input: int = 9
    """Size of the low-dimensional input: joint angles (6) + goal (3)."""
    low_dim_size: int = 64
    """Size of the low-dimensional (joints + goal) encoding."""
    spatial_softmax: bool = False
    """End each view's conv stack in a spatial softmax (Levine et al., 2016, "End-to-end
    training of deep visuomotor policies"): each channel's last conv map becomes the expected
    image position (x, y) of its activation, so a view's features are 2 * num_channels
    keypoint coordinates instead of the flattened map. Off = the paper's flattened features."""

    def __post_init__(self) -> None:
        if conv_output_size(self.image_size, self.strides, self.kernel_size) < 1:
            raise ValueError(
                f"image_size {self.image_size} is too small for strides {self.strides} "
                f"with kernel {self.kernel_size}"
            )

    @property
    def conv_output_side(self) -> int:
        """Side of each view's last conv feature map, pixels."""
        return conv_output_size(self.image_size, self.strides, self.kernel_size)

    @property
    def view_feature_dim(self) -> int:
        """Size F of one view's conv features: the flattened map, or 2 coordinates per channel
        with ``spatial_softmax``."""
        if self.spatial_softmax:
            return 2 * self.num_channels
        return self.num_channels * self.conv_output_side**2


def conv_output_size(image_size: int, strides: tuple[int, ...], kernel_size: int) -> int:
    """Side of the feature map after unpadded convs with these strides (<= 0: too small)."""
    side = image_size
    for stride in strides:
        side = (side - kernel_size) // stride + 1
        if side < 1:
            return 0
    return side


class SpatialSoftmax(nn.Module):
    """(N, C, H, W) feature maps -> (N, 2C) expected (x, y) of each channel's activation.

    Each channel's map is a softmax over its H * W positions, with a learned temperature; the
    output is the softmax-weighted mean of the pixel coordinates, in [-1, 1] (x left to right,
    y top to bottom), interleaved as (x_1, y_1, x_2, y_2, ...). The coordinates are sub-pixel:
    a keypoint can be located more finely than the map's grid.
    """

    def __init__(self, height: int, width: int) -> None:
        super().__init__()
        ys, xs = torch.meshgrid(
            torch.linspace(-1.0, 1.0, height), torch.linspace(-1.0, 1.0, width), indexing="ij"
        )
        self.register_buffer("grid", torch.stack([xs.flatten(), ys.flatten()], dim=1))
        self.log_temperature = nn.Parameter(torch.zeros(()))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        logits = features.flatten(2) / self.log_temperature.exp()  # (N, C, H * W)
        attention = torch.softmax(logits, dim=-1)
        return (attention @ self.grid).flatten(1)  # (N, C, 2) -> (N, 2C)


def _conv_stack(config: EncoderConfig) -> nn.Sequential:
    layers: list[nn.Module] = []
    channels = config.in_channels
    for stride in config.strides:
        layers += [nn.Conv2d(channels, config.num_channels, config.kernel_size, stride), nn.ReLU()]
        channels = config.num_channels
    if config.spatial_softmax:
        # The softmax takes the last conv's signed responses, not their ReLU.
        side = config.conv_output_side
        layers[-1] = SpatialSoftmax(side, side)
    return nn.Sequential(*layers)


def to_unit_float(images: torch.Tensor, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """uint8 images scaled to `dtype` (float32) in [0, 1]; floating images are returned
    unchanged (float32) or cast (other dtypes)."""
    if images.dtype == torch.uint8:
        return images.to(dtype).mul_(1.0 / 255.0)
    if not images.is_floating_point():
        raise TypeError(f"images must be uint8 or floating, got {images.dtype}")
    return images if dtype == torch.float32 else images.to(dtype)


class MultiViewEncoder(nn.Module):
    """V RGBD views -> visual encoding (B, feature_dim); see the module docstring.

    ``forward(images, view_mask)`` is ``merge(conv_trunk(images), view_mask)``; a training step
    that also needs the per-view features (contrastive terms) calls the two halves itself, so the
    convs run once.
    """

    def __init__(self, config: EncoderConfig) -> None:
        super().__init__()
        self.config = config
        num_trunks = 1 if config.share_view_weights else config.num_views
        self.trunks = nn.ModuleList(_conv_stack(config) for _ in range(num_trunks))
        if config.channels_last:  # kernels in oneDNN's layout too, so no reorder per call
            self.trunks.to(memory_format=torch.channels_last)
        num_views, view_dim, hidden = config.num_views, config.view_feature_dim, config.hidden_dim
        # nn.Linear's default init for a dense layer on concat(features, mask indicator).
        fan_in = num_views * view_dim + (num_views if config.view_mask_indicator else 0)
        bound = 1.0 / math.sqrt(fan_in)
        self.view_weight = nn.Parameter(
            torch.empty(num_views, view_dim, hidden).uniform_(-bound, bound)
        )
        self.mask_weight: nn.Parameter | None = None
        if config.view_mask_indicator:
            self.mask_weight = nn.Parameter(torch.empty(num_views, hidden).uniform_(-bound, bound))
        self.hidden_bias = nn.Parameter(torch.empty(hidden).uniform_(-bound, bound))
        self.head = nn.Linear(hidden, config.feature_dim)
        self.norm = nn.LayerNorm(config.feature_dim) if config.output_layer_norm else None

    def conv_trunk(self, images: torch.Tensor) -> torch.Tensor:
        """Per-view conv features (flattened maps, or keypoints with ``spatial_softmax``).

        Args:
            images: (B, V, C, H, W) uint8 in [0, 255] (scaled by 1/255 here), or floating
                already in [0, 1]; H = W = ``config.image_size``.

        Returns:
            (B, V, F) float32, F = ``config.view_feature_dim``.
        """
        cfg = self.config
        view_shape = (cfg.num_views, cfg.in_channels, cfg.image_size, cfg.image_size)
        if images.dim() != 5 or images.shape[1:] != view_shape:
            raise ValueError(f"expected images (B, *{view_shape}), got {tuple(images.shape)}")
        batch, num_views = images.shape[:2]
        if cfg.share_view_weights:
            # All views as one batch of B * V images through the same convs.
            features = self._run_trunk(self.trunks[0], images.flatten(0, 1))
            return features.reshape(batch, num_views, -1)
        # One conv stack per view. (A grouped conv does the same in one call, but measured
        # 1.5x slower on CPU than this loop.)
        per_view = [self._run_trunk(trunk, images[:, v]) for v, trunk in enumerate(self.trunks)]
        return torch.stack(per_view, dim=1)

    def _run_trunk(self, trunk: nn.Module, images: torch.Tensor) -> torch.Tensor:
        """(N, C, H, W) uint8 or float -> (N, F) float32, in cache-sized chunks on a CPU."""
        chunk = self.config.cpu_conv_chunk
        if chunk is None or images.device.type != "cpu" or len(images) <= chunk:
            return self._trunk_features(trunk, images)
        return torch.cat([self._trunk_features(trunk, part) for part in images.split(chunk)])

    def _trunk_features(self, trunk: nn.Module, images: torch.Tensor) -> torch.Tensor:
        cfg = self.config
        bf16 = cfg.bf16_autocast and bf16_enabled(images.device.type)
        if bf16:  # uint8 -> bf16 directly: a float32 copy would cost a pass more
            x = to_unit_float(images, torch.bfloat16)
        else:
            x = to_unit_float(images)
        if cfg.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        # Without grad (acting, targets) as plain calls, and no autocast context where it would
        # be off: between an env's renders, with the caches cold, each module call and the
        # context's entry cost about as much as a small conv (`clamgen.agents.fast_act`).
        layers = trunk if torch.is_grad_enabled() else functools.partial(run_layers, trunk)
        if not bf16:
            return layers(x).float().flatten(1)
        with torch.autocast(x.device.type, dtype=torch.bfloat16):
            return layers(x).float().flatten(1)

    def project(self, view_features: torch.Tensor) -> torch.Tensor:
        """W_v f_v for each view, the first dense layer's per-view part: (B, V, F) ->
        (B, V, hidden). :meth:`merge_projected` and :meth:`single_views_projected` take it, so
        a training step that needs both computes it once. One observation without gradients
        (acting) takes :meth:`project_nonzero`."""
        if len(view_features) == 1 and not torch.is_grad_enabled():
            return self.project_nonzero(view_features)
        # unbind (not indexing) so the backward pass stacks the gradients in one allocation.
        per_view = zip(view_features.unbind(1), self.view_weight.unbind(0), strict=True)
        return torch.stack([f @ w for f, w in per_view], dim=1)

    def project_nonzero(self, view_features: torch.Tensor) -> torch.Tensor:
        """:meth:`project` of one observation (1, V, F), over each view's nonzero features
        only. After the convs' ReLU most features are exactly 0 (86-88% for the shipped
        policies on blocked tasks), so this reads that much less of W_v (1.3 MB a view at
        F = 1296, hidden 256): acting between renders, with W out of the CPU's caches, the
        dense product was the policy's largest cost. The same sum without its zero terms,
        in another order (equal to float32 rounding); a view with more than
        `SPARSE_MAX_DENSITY` of its features nonzero (keypoints) takes the dense product."""
        rows = []
        for features, weight in zip(view_features[0], self.view_weight, strict=True):
            nonzero = features.nonzero().squeeze(1)
            if len(nonzero) > SPARSE_MAX_DENSITY * len(features):
                rows.append(features @ weight)
            else:
                kept = features.index_select(0, nonzero)
                rows.append(kept @ weight.index_select(0, nonzero))
        return torch.stack(rows)[None]

    def _dense_head(self, pre_activation: torch.Tensor) -> torch.Tensor:
        encoding = self.head(F.relu(pre_activation))
        if self.norm is not None:
            encoding = torch.tanh(self.norm(encoding))
        return encoding

    def merge(
        self, view_features: torch.Tensor, view_mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Visual encoding from per-view conv features, with dropped views zeroed.

        Equal to two dense layers on ``concat(mask_v * s * f_v for v, [mask])`` where s is 1 or,
        with ``rescale_kept_views``, V / (number of kept views).

        Args:
            view_features: (B, V, F) float32 from :meth:`conv_trunk`.
            view_mask: (B, V) bool, True = view kept; None keeps every view. Each row must keep
                at least one view.

        Returns:
            (B, feature_dim) float32; in (-1, 1) with ``output_layer_norm``.
        """
        return self.merge_projected(self.project(view_features), view_mask)

    def merge_projected(
        self, projections: torch.Tensor, view_mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        """:meth:`merge` from :meth:`project`'s (B, V, hidden) output."""
        if view_mask is None:
            pre_activation = projections.sum(1) + self.hidden_bias
            if self.mask_weight is not None:
                pre_activation = pre_activation + self.mask_weight.sum(0)
            return self._dense_head(pre_activation)
        mask = view_mask.to(projections.dtype)
        scale = mask
        if self.config.rescale_kept_views:
            scale = mask * (mask.shape[1] / mask.sum(1, keepdim=True).clamp_min(1.0))
        pre_activation = torch.einsum("bvh,bv->bh", projections, scale) + self.hidden_bias
        if self.mask_weight is not None:
            pre_activation = pre_activation + mask @ self.mask_weight
        return self._dense_head(pre_activation)

    def single_view_encodings(self, view_features: torch.Tensor) -> torch.Tensor:
        """Encoding of each view alone, as :meth:`merge` with every other view dropped.

        These embeddings live in the same space as the merged encoding, so the across-view
        contrastive term pulls together what one camera and another see of the same scene.

        Args:
            view_features: (B, V, F) float32 from :meth:`conv_trunk`.

        Returns:
            (B, V, feature_dim) float32.
        """
        return self.single_views_projected(self.project(view_features))

    def single_views_projected(self, projections: torch.Tensor) -> torch.Tensor:
        """:meth:`single_view_encodings` from :meth:`project`'s (B, V, hidden) output."""
        if self.config.rescale_kept_views:
            projections = projections * self.config.num_views
        pre_activation = projections + self.hidden_bias
        if self.mask_weight is not None:
            pre_activation = pre_activation + self.mask_weight  # one-hot mask of view v
        return self._dense_head(pre_activation)

    def forward(self, images: torch.Tensor, view_mask: torch.Tensor | None = None) -> torch.Tensor:
        """Visual encoding (B, feature_dim) of images (B, V, C, H, W); see :meth:`merge`."""
        return self.merge(self.conv_trunk(images), view_mask)


class LowDimEncoder(nn.Module):
    """Joint angles + goal -> encoding: one dense layer + ReLU (paper's "joint encoding").

    Inputs should already be normalised (e.g. :class:`clamgen.agents.networks.RunningNormalizer`):
    joint angles in radians and goals in metres differ in scale by an order of magnitude.
    """

    def __init__(self, input_dim: int, encoding_dim: int) -> None:
        super().__init__()
        self.dense = nn.Linear(input_dim, encoding_dim)

    @classmethod
    def from_config(cls, config: EncoderConfig) -> LowDimEncoder:
        """Sized by ``config.low_dim_input`` and ``config.low_dim_size``."""
        return cls(config.low_dim_input, config.low_dim_size)

    def forward(self, low_dim: torch.Tensor) -> torch.Tensor:
        """(B, input_dim) float32 -> (B, encoding_dim) float32, non-negative."""
        return F.relu(self.dense(low_dim))


def fuse(visual: torch.Tensor, low_dim: torch.Tensor) -> torch.Tensor:
    """Multi-modal embedding: concat of visual (B, Dv) and low-dim (B, Dl) -> (B, Dv + Dl)."""
    return torch.cat([visual, low_dim], dim=-1)


def view_dropout_mask(
    batch_size: int,
    num_views: int,
    drop_prob: float,
    generator: torch.Generator | None = None,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """Random view-dropout mask that never drops every view of a sample.

    Each view is dropped independently with probability ``drop_prob``; in a sample where that
    dropped all of them, one view drawn uniformly is kept instead. A view is therefore dropped at
    rate ``p - p**V / V`` (0.245 for p = 0.25, V = 3), and with V = 1 never.

    Args:
        batch_size: number B of samples.
        num_views: number V of views per sample.
        drop_prob: probability p in [0, 1] of dropping each view.
        generator: torch generator for reproducible masks (on ``device``); None uses the global.
        device: device of the mask (default: the generator's, else CPU).

    Returns:
        (B, V) bool, True = view kept; every row has at least one True.
    """
    if not 0.0 <= drop_prob <= 1.0:
        raise ValueError(f"drop_prob must be in [0, 1], got {drop_prob}")
    if device is None:
        device = generator.device if generator is not None else "cpu"
    shape = (batch_size, num_views)
    kept = torch.rand(shape, generator=generator, device=device) >= drop_prob
    rescue = torch.randint(num_views, (batch_size,), generator=generator, device=device)
    none_kept = ~kept.any(1)
    kept[none_kept, rescue[none_kept]] = True
    return kept
