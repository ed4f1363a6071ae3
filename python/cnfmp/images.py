"""Decoding images that arrive as bytes (from the CLI, the HTTP API, the bridge), with the
checks every entry point shares: empty, unreadable, truncated, or absurdly large input is an
:class:`InputError` naming the problem, never a decoder traceback."""

from __future__ import annotations

import io

import numpy as np

from cnfmp.errors import InputError

#: Colours of label maps in pictures: background black, then one colour per object slot.
LABEL_PALETTE = np.array([[0, 0, 0], [230, 25, 75], [60, 180, 75], [0, 130, 200], [255, 225, 25], [145, 30, 180]],
                         np.uint8)

#: Largest image side accepted (px); the networks work at 64-128 px, anything larger is waste.
MAX_IMAGE_SIDE = 4096


def _open_image(data: bytes, what: str):
    from PIL import Image, UnidentifiedImageError

    if not data:
        raise InputError(f"{what} is empty")
    try:
        image = Image.open(io.BytesIO(data))
        if max(image.size) > MAX_IMAGE_SIDE or min(image.size) < 1:
            raise InputError(f"{what} is {image.size[0]}x{image.size[1]}; sides must be 1..{MAX_IMAGE_SIDE} px")
        image.load()
    except UnidentifiedImageError:
        raise InputError(f"{what} is not an image in a format we read (PNG, JPEG, BMP, ...)") from None
    except (OSError, SyntaxError, ValueError) as err:
        if isinstance(err, InputError):
            raise
        raise InputError(f"{what} is not a readable image: {err}") from None
    return image


def decode_image(data: bytes, what: str = "image") -> np.ndarray:
    """Encoded image bytes (PNG, JPEG, ...) -> (H, W, 3) uint8 RGB."""
    return np.asarray(_open_image(data, what).convert("RGB"))


def decode_labels(data: bytes, what: str = "masks") -> np.ndarray:
    """An 8-bit single-channel label map (PNG) -> (H, W) uint8."""
    image = _open_image(data, what)
    if image.mode not in ("L", "P"):
        raise InputError(f"{what} must be an 8-bit single-channel label map (0 background, k the k-th object), "
                         f"got image mode {image.mode}")
    return np.asarray(image, dtype=np.uint8)


def encode_png(array: np.ndarray) -> bytes:
    """(H, W) or (H, W, 3) uint8 -> PNG bytes."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(array)).save(buffer, format="PNG")
    return buffer.getvalue()


__all__ = ["MAX_IMAGE_SIDE", "decode_image", "decode_labels", "encode_png"]
