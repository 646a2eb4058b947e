"""Decoding uploaded image bytes with Pillow, refusing anything that is not an image."""

from __future__ import annotations

import io
import warnings
from collections.abc import Iterable, Iterator

from PIL import Image, UnidentifiedImageError

from service.errors import EmptyInputError, InvalidInputError

MAX_PIXELS = 64_000_000  # a decompression-bomb guard well above any camera frame
BATCH_PIXELS = 16_000_000  # decoded pixels held at once by a batch of several images


def decode_image(data: bytes, name: str = "image") -> Image.Image:
    """The decoded image (fully loaded), or :class:`InvalidInputError` naming the problem."""
    return _open(data, name, load=True)


def image_pixels(data: bytes, name: str = "image") -> int:
    """Width × height from the image's header alone (nothing is decoded), checked like
    :func:`decode_image` checks it."""
    img = _open(data, name, load=False)
    return int(img.width * img.height)


def decode_batches(blobs: Iterable[tuple[str, bytes]], max_images: int,
                   max_pixels: int = BATCH_PIXELS) -> Iterator[list[Image.Image]]:  # fmt: skip
    """Decoded images in batches of at most ``max_images`` and ``max_pixels`` decoded pixels
    (an image larger than that alone is a batch of one): memory holds one batch, not all."""
    batch: list[Image.Image] = []
    pixels = 0
    for name, data in blobs:
        n = image_pixels(data, name)
        if batch and (len(batch) >= max_images or pixels + n > max_pixels):
            yield batch
            batch, pixels = [], 0
        batch.append(decode_image(data, name))
        pixels += n
    if batch:
        yield batch


def _open(data: bytes, name: str, load: bool) -> Image.Image:
    if not data:
        raise EmptyInputError(f"{name} is empty (0 bytes)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            img = Image.open(io.BytesIO(data))
            if img.width * img.height > MAX_PIXELS:
                raise InvalidInputError(
                    f"{name} is {img.width}x{img.height} pixels, more than {MAX_PIXELS} allowed"
                )
            if load:
                img.load()
    except UnidentifiedImageError as exc:
        raise InvalidInputError(
            f"{name} is not a decodable image ({len(data)} bytes; PNG, JPEG, BMP, TIFF, … expected)"
        ) from exc
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise InvalidInputError(f"{name} is too large to decode: {exc}") from exc
    except (OSError, SyntaxError, ValueError) as exc:
        raise InvalidInputError(f"{name} is a truncated or corrupt image: {exc}") from exc
    return img
