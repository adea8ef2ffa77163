"""The ONE image preprocessing used for map and live images (numpy/OpenCV, no torch).

`prepare_image` resizes an HxWx3 uint8 RGB image to a model's fixed input size and returns a
(1, 3, h, w) float32 tensor; `to_input_pixels` / `to_image_pixels` convert pixel coordinates
between the input image and the network input, with pixel centres at integer coordinates:
u_net = (u_img + 0.5) * (w_net / w_img) - 0.5.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def check_rgb(image_rgb: NDArray[np.uint8]) -> None:
    if not isinstance(image_rgb, np.ndarray) or image_rgb.dtype != np.uint8:
        raise ValueError(
            f"image must be a uint8 numpy array, got {getattr(image_rgb, 'dtype', type(image_rgb))}"
        )
    if (
        image_rgb.ndim != 3
        or image_rgb.shape[2] != 3
        or image_rgb.shape[0] < 2
        or image_rgb.shape[1] < 2
    ):
        raise ValueError(f"image must be HxWx3 RGB, got shape {image_rgb.shape}")


def resize_image(image_rgb: NDArray[np.uint8], size_hw: tuple[int, int]) -> NDArray[np.uint8]:
    """HxWx3 uint8 -> h x w x 3 uint8: INTER_AREA when shrinking both axes, else INTER_LINEAR."""
    check_rgb(image_rgb)
    h, w = size_hw
    ih, iw = image_rgb.shape[:2]
    if (ih, iw) == (h, w):
        return image_rgb
    interp = cv2.INTER_AREA if (ih >= h and iw >= w) else cv2.INTER_LINEAR
    resized = cv2.resize(image_rgb, (w, h), interpolation=interp)
    out: NDArray[np.uint8] = np.asarray(resized, np.uint8)
    return out


def prepare_image(
    image_rgb: NDArray[np.uint8],
    size_hw: tuple[int, int],
    mean: tuple[float, float, float] | None = None,
    std: tuple[float, float, float] | None = None,
) -> NDArray[np.float32]:
    """HxWx3 uint8 RGB -> (1, 3, h, w) float32 network input.

    Resizes to `size_hw` = (h, w) exactly with `resize_image` (aspect ratio is not kept:
    keypoints are mapped back per axis by `to_image_pixels`); scales to
    [0, 1]; then, if given, subtracts `mean` and divides by `std` per RGB channel.
    """
    image_rgb = resize_image(image_rgb, size_hw)
    x: NDArray[np.float32] = image_rgb.astype(np.float32) * np.float32(1.0 / 255.0)
    if mean is not None and std is not None:
        x = ((x - np.asarray(mean, np.float32)) / np.asarray(std, np.float32)).astype(np.float32)
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None])


def to_image_pixels(
    xy_net: NDArray[np.float32], net_size_wh: tuple[int, int], image_size_wh: tuple[int, int]
) -> NDArray[np.float32]:
    """(N, 2) pixel coordinates in the network input -> the original image's pixels."""
    s = np.asarray(image_size_wh, np.float64) / np.asarray(net_size_wh, np.float64)
    return ((xy_net.astype(np.float64) + 0.5) * s - 0.5).astype(np.float32)


def to_input_pixels(
    xy_img: NDArray[np.float32], net_size_wh: tuple[int, int], image_size_wh: tuple[int, int]
) -> NDArray[np.float32]:
    """Inverse of `to_image_pixels`."""
    s = np.asarray(net_size_wh, np.float64) / np.asarray(image_size_wh, np.float64)
    return ((xy_img.astype(np.float64) + 0.5) * s - 0.5).astype(np.float32)
