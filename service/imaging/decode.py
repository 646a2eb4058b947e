"""Decoding uploaded image bytes with Pillow, refusing anything that is not an image."""

from __future__ import annotations

import io
import warnings

from PIL import Image, UnidentifiedImageError

from service.errors import EmptyInputError, InvalidInputError

MAX_PIXELS = 64_000_000  # a decompression-bomb guard well above any camera frame


def decode_image(data: bytes, name: str = "image") -> Image.Image:
    """The decoded image (fully loaded), or :class:`InvalidInputError` naming the problem."""
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
