"""Run-time settings of the image extractors (``GRIDPLACE_EXTRACTOR_*`` environment variables).

They change how fast descriptors are made, never what they are: a map version's stored
extractor config alone decides the descriptor.
"""

from __future__ import annotations

import os
from typing import Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class ImagingSettings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="GRIDPLACE_", env_file=None, extra="ignore")

    extractor_device: Literal["auto", "cpu", "cuda"] = Field(
        "auto", description="where CNN extractors run: auto = CUDA when visible, else CPU"
    )
    extractor_threads: int = Field(
        1, ge=0, le=256, description="CPU threads of one CNN forward (0 = every core). One by "
        "default: on a machine shared with other work, intra-op threads that wait for each "
        "other made a forward several times slower than one thread",
    )  # fmt: skip
    extractor_batch_size: int = Field(
        32, ge=1, le=4096, description="images per CNN forward pass"
    )

    def threads(self) -> int:
        return self.extractor_threads or max(1, os.cpu_count() or 1)
