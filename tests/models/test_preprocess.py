"""The one preprocessing function (map and live images) and the pixel-centre-aware mapping."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.models import aliked, classical, vpr
from litevloc.models.preprocess import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    prepare_image,
    resize_image,
    to_image_pixels,
    to_input_pixels,
)


def test_prepare_image_shape_range_and_determinism() -> None:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    x = prepare_image(img, (240, 320))
    assert x.shape == (1, 3, 240, 320) and x.dtype == np.float32 and x.flags.c_contiguous
    assert x.min() >= 0.0 and x.max() <= 1.0
    # a "map" image and the same "live" image give bit-identical inputs
    np.testing.assert_array_equal(x, prepare_image(img.copy(), (240, 320)))
    # same size: no resampling, only scaling; channel order kept (RGB)
    y = prepare_image(img, (480, 640))
    np.testing.assert_allclose(y[0, 0], img[..., 0] / 255.0, atol=1e-7)
    z = prepare_image(img, (480, 640), IMAGENET_MEAN, IMAGENET_STD)
    np.testing.assert_allclose(
        z[0, 2], (img[..., 2] / 255.0 - IMAGENET_MEAN[2]) / IMAGENET_STD[2], atol=1e-5
    )


def test_prepare_image_area_resize_is_block_mean() -> None:
    img = np.zeros((4, 4, 3), np.uint8)
    img[:2, :2] = 200  # top-left 2x2 block
    x = prepare_image(img, (2, 2))
    np.testing.assert_allclose(x[0, :, 0, 0], 200 / 255.0, atol=1e-6)
    np.testing.assert_allclose(x[0, :, 1, 1], 0.0, atol=1e-6)


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((10, 10), np.uint8),
        np.zeros((10, 10, 3), np.float32),
        np.zeros((10, 10, 4), np.uint8),
    ],
)
def test_prepare_image_rejects_bad_input(bad: np.ndarray) -> None:
    with pytest.raises(ValueError, match="image must be"):
        prepare_image(bad, (8, 8))


def test_pixel_mapping_is_centre_aware() -> None:
    net, img = (320, 240), (640, 480)
    # the centre of network pixel 0 covers image pixels 0 and 1 -> image coordinate 0.5
    np.testing.assert_allclose(
        to_image_pixels(np.array([[0.0, 0.0]], np.float32), net, img), [[0.5, 0.5]]
    )
    # the last network pixel centre (319) -> 638.5; the image's outer edge -0.5 maps to itself
    np.testing.assert_allclose(
        to_image_pixels(np.array([[319.0, 239.0]], np.float32), net, img), [[638.5, 478.5]]
    )
    np.testing.assert_allclose(
        to_image_pixels(np.array([[-0.5, -0.5]], np.float32), net, img), [[-0.5, -0.5]]
    )
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.5, 639.5, (100, 2)).astype(np.float32)
    np.testing.assert_allclose(
        to_image_pixels(to_input_pixels(pts, net, img), net, img), pts, atol=1e-3
    )
    # anisotropic: 640x360 image into a 320x240 network input
    np.testing.assert_allclose(
        to_image_pixels(np.array([[0.0, 0.0]], np.float32), (320, 240), (640, 360)), [[0.5, 0.25]]
    )


def test_every_wrapper_uses_the_one_preprocessing() -> None:
    """Map and live images go through the same code: the ONNX wrappers call prepare_image and
    the OpenCV extractors share its resize."""
    assert aliked.prepare_image is prepare_image
    assert vpr.prepare_image is prepare_image
    assert classical.to_image_pixels is to_image_pixels
    assert classical.resize_image is resize_image
