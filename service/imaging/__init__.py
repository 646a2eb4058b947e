"""Images → descriptors: pluggable extractors described by a JSON config stored per version."""

from service.imaging.config import (
    DEFAULT_EXTRACTOR,
    CnnConfig,
    HogConfig,
    PatchNormConfig,
    parse_extractor_config,
)
from service.imaging.decode import decode_image, image_pixels
from service.imaging.extractors import Extractor, make_extractor
from service.imaging.files import extract_blobs, extract_paths, is_image_name, list_images

__all__ = [
    "DEFAULT_EXTRACTOR",
    "CnnConfig",
    "Extractor",
    "HogConfig",
    "PatchNormConfig",
    "decode_image",
    "extract_blobs",
    "extract_paths",
    "image_pixels",
    "is_image_name",
    "list_images",
    "make_extractor",
    "parse_extractor_config",
]
