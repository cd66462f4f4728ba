"""Multi-view encoder, view dropout and crop augmentation: shapes, gradient flow, that merging
equals a dense layer on the masked concatenation, weight sharing, mask statistics, crops."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from hypothesis import given, settings
from hypothesis import strategies as st

from clamgen.agents.augment import center_crop, edge_pad, random_crop
from clamgen.agents.encoders import (
    EMULATED_BF16_ENV,
    EncoderConfig,
    LowDimEncoder,
    MultiViewEncoder,
    SpatialSoftmax,
    conv_output_size,
    fuse,
    view_dropout_mask,
)

torch.set_num_threads(1)

TINY = EncoderConfig(
    image_size=16, num_views=3, num_channels=8, strides=(2, 1, 1, 1), hidden_dim=32, feature_dim=12
)


def make_encoder(config: EncoderConfig = TINY, seed: int = 0) -> MultiViewEncoder:
    torch.manual_seed(seed)
    return MultiViewEncoder(config)


def random_images(config: EncoderConfig, batch: int, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    shape = (batch, config.num_views, config.in_channels, config.image_size, config.image_size)
    return torch.randint(0, 256, shape, dtype=torch.uint8, generator=generator)


def conv_parameter_count(encoder: MultiViewEncoder) -> int:
    return sum(p.numel() for p in encoder.trunks.parameters())


# --- encoder -----------------------------------------------------------------------------------


def test_conv_output_size_matches_the_conv_stack() -> None:
    assert conv_output_size(84, (2, 1, 1, 1), 3) == 35  # CURL's 35 x 35 x 32 features
    assert conv_output_size(64, (2, 2, 1, 1), 3) == 11
    features = make_encoder().conv_trunk(random_images(TINY, 2))
    assert features.shape == (2, TINY.num_views, TINY.view_feature_dim)
    assert TINY.view_feature_dim == TINY.num_channels * conv_output_size(16, TINY.strides, 3) ** 2


def test_too_small_image_is_rejected() -> None:
    with pytest.raises(ValueError, match="too small"):
        EncoderConfig(image_size=8, strides=(2, 2, 2, 2))


def test_output_shapes_and_range() -> None:
    encoder = make_encoder()
    images = random_images(TINY, 5)
    encoding = encoder(images)
    assert encoding.shape == (5, TINY.feature_dim) and encoding.dtype == torch.float32
    assert encoding.abs().max() < 1.0  # LayerNorm + tanh
    views = encoder.single_view_encodings(encoder.conv_trunk(images))
    assert views.shape == (5, TINY.num_views, TINY.feature_dim)
    low_dim = LowDimEncoder.from_config(TINY)(torch.randn(5, TINY.low_dim_input))
    assert low_dim.shape == (5, TINY.low_dim_size) and (low_dim >= 0).all()
    assert fuse(encoding, low_dim).shape == (5, TINY.feature_dim + TINY.low_dim_size)


def test_acting_projection_over_nonzero_features_equals_the_dense_one() -> None:
    """One observation without gradients skips each view's zero features (after the ReLU,
    most of them): the same product, to float32 rounding, sparse and dense views alike."""
    encoder = make_encoder()
    generator = torch.Generator().manual_seed(3)
    features = torch.rand(1, TINY.num_views, TINY.view_feature_dim, generator=generator)
    zero = torch.rand(features.shape, generator=generator) < 0.85
    features[0, :2][zero[0, :2]] = 0.0  # views 0 and 1 sparse, view 2 dense
    dense = torch.einsum("bvf,vfh->bvh", features, encoder.view_weight)
    with torch.no_grad():
        acting = encoder.project(features)
    torch.testing.assert_close(acting, dense, rtol=1e-5, atol=1e-6)
    features[0, 0] = 0.0  # a view that shows nothing
    with torch.no_grad():
        assert encoder.project(features)[0, 0].abs().max() == 0.0


def test_wrong_image_shape_is_rejected() -> None:
    with pytest.raises(ValueError, match="expected images"):
        make_encoder()(random_images(dataclasses.replace(TINY, num_views=2), 2))


def test_uint8_is_scaled_to_unit_range() -> None:
    encoder = make_encoder()
    images = random_images(TINY, 3)
    expected = encoder(images.float() / 255.0)
    torch.testing.assert_close(encoder(images), expected)


@pytest.mark.parametrize("shared", [True, False])
def test_chunked_convs_match_one_call(shared: bool) -> None:
    config = dataclasses.replace(TINY, share_view_weights=shared, cpu_conv_chunk=None)
    one_call = make_encoder(config)
    chunked = make_encoder(dataclasses.replace(config, cpu_conv_chunk=2))
    images = random_images(TINY, 5)
    torch.testing.assert_close(chunked.conv_trunk(images), one_call.conv_trunk(images))


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"share_view_weights": False},
        {"channels_last": False},
        {"spatial_softmax": True, "image_size": 32},  # 9 x 9 keypoint maps
        {"bf16_autocast": True},  # emulated here (the same maths as in hardware)
    ],
    ids=["shared", "per-view", "nchw", "keypoints", "bf16"],
)
def test_the_convs_without_grad_give_the_module_calls_features_bit_for_bit(
    changes: dict, monkeypatch
) -> None:
    monkeypatch.setenv(EMULATED_BF16_ENV, "1")
    encoder = make_encoder(dataclasses.replace(TINY, **changes))
    images = random_images(encoder.config, 2)
    with torch.no_grad():  # plain functional calls (`run_layers`)
        plain = encoder(images), encoder.conv_trunk(images)
    modules = encoder(images).detach(), encoder.conv_trunk(images).detach()  # module calls
    for got, expected in zip(plain, modules, strict=True):
        assert torch.equal(got, expected)


@pytest.mark.parametrize("shared", [True, False])
def test_gradients_reach_every_parameter(shared: bool) -> None:
    config = dataclasses.replace(TINY, share_view_weights=shared)
    encoder = make_encoder(config)
    low_dim_encoder = LowDimEncoder.from_config(config)
    mask = torch.tensor([[True, False, True], [True, True, True], [False, False, True]])
    fused = fuse(encoder(random_images(config, 3), mask), low_dim_encoder(torch.randn(3, 9)))
    fused.pow(2).sum().backward()
    for name, param in [*encoder.named_parameters(), *low_dim_encoder.named_parameters()]:
        assert param.grad is not None and param.grad.abs().sum() > 0, name


def test_spatial_softmax_finds_a_bright_spot() -> None:
    layer = SpatialSoftmax(5, 9)
    with torch.no_grad():
        layer.log_temperature.fill_(-3.0)  # sharp: nearly all the weight on the peak
    maps = torch.zeros(1, 2, 5, 9)
    maps[0, 0, 4, 0] = 10.0  # bottom-left corner
    maps[0, 1, 2, 6] = 10.0  # middle row, 7th of 9 columns
    keypoints = layer(maps)
    torch.testing.assert_close(keypoints, torch.tensor([[-1.0, 1.0, 0.5, 0.0]]), atol=1e-4, rtol=0)
    assert layer(torch.zeros(1, 1, 5, 9)).abs().max() < 1e-6  # flat map: the centre


def test_spatial_softmax_encoder_shapes_and_gradients() -> None:
    config = dataclasses.replace(TINY, image_size=32, spatial_softmax=True)  # 9 x 9 maps
    assert config.view_feature_dim == 2 * config.num_channels
    encoder = make_encoder(config)
    features = encoder.conv_trunk(random_images(config, 3))
    assert features.shape == (3, config.num_views, 2 * config.num_channels)
    assert features.abs().max() <= 1.0
    encoder(random_images(config, 3)).pow(2).sum().backward()
    for name, param in encoder.named_parameters():
        assert param.grad is not None and param.grad.abs().sum() > 0, name


@pytest.mark.parametrize("indicator", [True, False])
@pytest.mark.parametrize("rescale", [True, False])
def test_merge_is_a_dense_layer_on_the_masked_concatenation(indicator: bool, rescale: bool) -> None:
    config = dataclasses.replace(TINY, view_mask_indicator=indicator, rescale_kept_views=rescale)
    encoder = make_encoder(config)
    features = encoder.conv_trunk(random_images(config, 4))
    mask = torch.tensor([[True, True, True], [True, False, True], [False, True, False]] * 2)[:4]
    kept = mask.float()
    scale = kept * (3.0 / kept.sum(1, keepdim=True)) if rescale else kept
    parts = [(features * scale[..., None]).flatten(1)]
    weights = [encoder.view_weight.flatten(0, 1)]
    if indicator:
        parts.append(kept)
        weights.append(encoder.mask_weight)
    hidden = F.relu(torch.cat(parts, 1) @ torch.cat(weights, 0) + encoder.hidden_bias)
    expected = torch.tanh(encoder.norm(encoder.head(hidden)))
    torch.testing.assert_close(encoder.merge(features, mask), expected, rtol=1e-5, atol=1e-5)
    all_kept = torch.ones(4, 3, dtype=torch.bool)
    torch.testing.assert_close(encoder.merge(features), encoder.merge(features, all_kept))


def test_single_view_encoding_is_merge_with_the_other_views_dropped() -> None:
    encoder = make_encoder(dataclasses.replace(TINY, rescale_kept_views=True))
    features = encoder.conv_trunk(random_images(TINY, 4))
    single = encoder.single_view_encodings(features)
    for view in range(TINY.num_views):
        mask = torch.zeros(4, TINY.num_views, dtype=torch.bool)
        mask[:, view] = True
        torch.testing.assert_close(single[:, view], encoder.merge(features, mask))


def test_dropped_view_does_not_affect_the_encoding() -> None:
    encoder = make_encoder()
    images = random_images(TINY, 2)
    changed = images.clone()
    changed[:, 1] = random_images(TINY, 2, seed=1)[:, 1]
    mask = torch.tensor([[True, False, True]] * 2)
    torch.testing.assert_close(encoder(images, mask), encoder(changed, mask))
    assert not torch.allclose(encoder(images), encoder(changed))


def test_shared_weights_share_the_conv_parameters() -> None:
    shared = make_encoder(dataclasses.replace(TINY, share_view_weights=True))
    separate = make_encoder(dataclasses.replace(TINY, share_view_weights=False))
    one_stack = 4 * 8 * 9 + 8 + 3 * (8 * 8 * 9 + 8)
    assert conv_parameter_count(shared) == one_stack
    assert conv_parameter_count(separate) == TINY.num_views * one_stack
    # The dense layers read the concatenation either way, so they have the same size.
    dense = sum(p.numel() for n, p in shared.named_parameters() if not n.startswith("trunks"))
    assert sum(p.numel() for p in shared.parameters()) == one_stack + dense
    # The same picture in every view gives the same conv features only with shared weights.
    images = random_images(TINY, 2)[:, :1].expand(-1, TINY.num_views, -1, -1, -1)
    shared_features = shared.conv_trunk(images)
    separate_features = separate.conv_trunk(images)
    torch.testing.assert_close(shared_features[:, 0], shared_features[:, 2])
    assert not torch.allclose(separate_features[:, 0], separate_features[:, 2])


# --- view dropout ------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    batch=st.integers(1, 64),
    num_views=st.integers(1, 4),
    drop_prob=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**31 - 1),
)
def test_view_dropout_never_drops_every_view(
    batch: int, num_views: int, drop_prob: float, seed: int
) -> None:
    generator = torch.Generator().manual_seed(seed)
    mask = view_dropout_mask(batch, num_views, drop_prob, generator)
    assert mask.shape == (batch, num_views) and mask.dtype == torch.bool
    assert mask.any(1).all()


@pytest.mark.parametrize("num_views", [2, 3, 4])
@pytest.mark.parametrize("drop_prob", [0.1, 0.25, 0.5])
def test_view_dropout_rate(num_views: int, drop_prob: float) -> None:
    mask = view_dropout_mask(100_000, num_views, drop_prob, torch.Generator().manual_seed(0))
    dropped = (~mask).float().mean(0)
    expected = drop_prob - drop_prob**num_views / num_views
    # Binomial standard error is < 0.0016 per view at this size.
    np.testing.assert_allclose(dropped.numpy(), expected, atol=0.006)


def test_view_dropout_edge_cases_and_determinism() -> None:
    assert view_dropout_mask(50, 3, 0.0).all()
    assert (view_dropout_mask(50, 3, 1.0).sum(1) == 1).all()
    assert view_dropout_mask(50, 1, 0.9).all()
    first = view_dropout_mask(20, 3, 0.4, torch.Generator().manual_seed(7))
    assert torch.equal(first, view_dropout_mask(20, 3, 0.4, torch.Generator().manual_seed(7)))
    with pytest.raises(ValueError):
        view_dropout_mask(4, 3, 1.5)


# --- crops -------------------------------------------------------------------------------------


def test_random_crop_shape_and_windows() -> None:
    images = random_images(dataclasses.replace(TINY, image_size=20), 4)
    crops = random_crop(images, 16, torch.Generator().manual_seed(3))
    assert crops.shape == (4, 3, 4, 16, 16) and crops.dtype == torch.uint8
    # Each crop is the window at the offsets drawn from the same generator stream.
    generator = torch.Generator().manual_seed(3)
    top = torch.randint(5, (12,), generator=generator)
    left = torch.randint(5, (12,), generator=generator)
    flat = images.reshape(12, 4, 20, 20)
    for i, crop in enumerate(crops.reshape(12, 4, 16, 16)):
        assert torch.equal(crop, flat[i, :, top[i] : top[i] + 16, left[i] : left[i] + 16])
    assert random_crop(images[:, 0], 16).shape == (4, 4, 16, 16)


def test_random_crop_differs_per_sample_and_per_view() -> None:
    picture = random_images(dataclasses.replace(TINY, image_size=32, num_views=1), 1)
    images = picture.expand(16, 3, -1, -1, -1)
    crops = random_crop(images, 24, torch.Generator().manual_seed(0)).reshape(48, -1)
    assert len(torch.unique(crops, dim=0)) > 30  # 81 offsets; all-equal would give 1
    same = random_crop(images, 24, torch.Generator().manual_seed(0), same_offset_across_views=True)
    assert all(torch.equal(same[b, 0], same[b, v]) for b in range(16) for v in range(3))
    assert len(torch.unique(same[:, 0].reshape(16, -1), dim=0)) > 8


def test_edge_pad_repeats_the_border_pixels_as_numpy_edge_mode() -> None:
    images = random_images(dataclasses.replace(TINY, image_size=20), 2)
    padded = edge_pad(images, 3)
    assert padded.shape == (2, 3, 4, 26, 26) and padded.dtype == torch.uint8
    expected = np.pad(images.numpy(), [(0, 0)] * 3 + [(3, 3), (3, 3)], mode="edge")
    np.testing.assert_array_equal(padded.numpy(), expected)
    assert edge_pad(images, 0) is images
    with pytest.raises(ValueError, match="pad"):
        edge_pad(images, -1)


def test_center_crop_is_deterministic_and_centred() -> None:
    images = random_images(dataclasses.replace(TINY, image_size=20), 2)
    crop = center_crop(images, 16)
    assert crop.shape == (2, 3, 4, 16, 16)
    assert torch.equal(crop, images[..., 2:18, 2:18])
    assert torch.equal(crop, center_crop(images, 16))
    assert torch.equal(center_crop(images, 20), images)
    with pytest.raises(ValueError):
        center_crop(images, 21)
