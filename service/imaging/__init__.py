"""Images → descriptors: pluggable extractors described by a JSON config stored per version."""

from service.imaging.cnn_config import DEFAULT_PRESET, PRESETS
from service.imaging.config import (
    DEFAULT_EXTRACTOR,
    CnnConfig,
    HogConfig,
    PatchNormConfig,
    parse_extractor_config,
)
from service.imaging.decode import decode_image, image_pixels
from service.imaging.extractors import Extractor, clear_extractor_cache, make_extractor
from service.imaging.files import extract_blobs, extract_paths, is_image_name, list_images
from service.imaging.resumable import FolderExtraction, extract_folder
from service.imaging.settings import ImagingSettings

__all__ = [
    "DEFAULT_EXTRACTOR",
    "DEFAULT_PRESET",
    "PRESETS",
    "CnnConfig",
    "Extractor",
    "FolderExtraction",
    "HogConfig",
    "ImagingSettings",
    "PatchNormConfig",
    "clear_extractor_cache",
    "decode_image",
    "extract_blobs",
    "extract_folder",
    "extract_paths",
    "image_pixels",
    "is_image_name",
    "list_images",
    "make_extractor",
    "parse_extractor_config",
]
