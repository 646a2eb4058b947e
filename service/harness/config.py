"""The harness's budget: which sizes and parameter grids each experiment sweeps.

``quick`` fits in well under 30 minutes on 2 cores for a route of ~3,600 frames × 2,048
columns; ``full`` is the paper-sized sweep (finer grids, every trainer to the full route, all
queries of the long chunked route) and takes much longer.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

from service.errors import InvalidParameterError

EXPERIMENTS: tuple[str, ...] = ("storage", "timing", "patterns", "chunking", "retrieval")


@dataclass(frozen=True)
class BenchConfig:
    preset: str = "quick"
    experiments: tuple[str, ...] = EXPERIMENTS
    trainer: str = "ridge"  # trainer of every sweep except the per-trainer timing table
    dtype: str = "float32"  # storage dtype of every model
    seed: int = 0
    # CPU threads of the torch trainer; None = torch's default. One thread by default: on a
    # shared machine torch's spinning OpenMP threads can slow a fit down a hundredfold.
    torch_threads: int | None = 1
    # 1. storage scaling
    storage_n_points: int = 5
    storage_n_min: int = 100
    storage_rhos: tuple[float, ...] = (0.1, 0.25, 0.5, 1.0)
    storage_ks: tuple[int, ...] = (2, 3, 4)
    storage_methods: tuple[str, ...] = ("gridplace", "yu", "exact_nn")
    identical_targets: tuple[float, ...] = (0.99, 0.80)  # precision at tolerance 0, train = test
    cross_targets: tuple[float, ...] = (0.10, 0.02)  # precision at cross_tolerance
    cross_tolerance: int = 5
    # 2. training and query time
    timing_n_points: int = 5
    timing_n_min: int = 250
    timing_trainers: tuple[str, ...] = ("ridge", "torch", "logreg", "svm")
    timing_yu_trainers: tuple[str, ...] = ("ridge", "logreg")
    slow_trainers: tuple[str, ...] = ("logreg", "svm")
    slow_trainer_max_n: int = 1000  # slow trainers only up to this N (minutes per fit at 3.5k)
    timing_k: int = 2
    timing_rho: float = 0.5
    single_query_repeats: int = 20
    timing_repeats: int = 3  # fits per point for the fast trainers; the fastest one counts
    # 3. precision vs k
    pattern_ks: tuple[int, ...] = (2, 3, 4, 5)
    pattern_rho: float = 0.5
    # 4. chunking at scale
    chunk_n_frames: int = 89_000
    chunk_n_features: int = 512
    chunk_region_length: int = 300  # slowly varying scenery of the synthetic route (0 = none)
    chunk_n_chunks: int = 10
    chunk_k: int = 2
    chunk_rho: float = 0.5
    chunk_query_noise: float = 0.3
    chunk_n_queries: int | None = 10_000  # evenly spaced subset of the queries; None = all
    chunk_compare_unchunked: bool = True
    chunk_tolerances: tuple[int, ...] = (0, 1, 2, 5, 10, 25, 50, 100, 250)
    # 5. against retrieval
    retrieval_gridplace: tuple[tuple[int, float], ...] = ((2, 0.5), (3, 1.0))  # (k, ρ)
    retrieval_pq_m: tuple[int, ...] = (16, 64)
    retrieval_tolerances: tuple[int, ...] = (0, 1, 5, 10, 25)
    tolerances: tuple[int, ...] = (0, 1, 2, 5, 10, 25)

    def __post_init__(self) -> None:
        unknown = set(self.experiments) - set(EXPERIMENTS)
        if unknown:
            raise InvalidParameterError(
                f"unknown experiments {sorted(unknown)}; choose from {EXPERIMENTS}"
            )
        if self.cross_tolerance not in self.tolerances:
            raise InvalidParameterError("cross_tolerance must be one of the tolerances")

    @classmethod
    def quick(cls, **overrides: Any) -> BenchConfig:
        return replace(cls(), **overrides)

    @classmethod
    def full(cls, **overrides: Any) -> BenchConfig:
        base = cls(
            preset="full",
            storage_n_points=8,
            storage_rhos=(0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0),
            storage_ks=(2, 3, 4, 5),
            timing_n_points=7,
            timing_n_min=100,
            slow_trainer_max_n=1_000_000,
            single_query_repeats=50,
            chunk_n_features=1024,
            chunk_n_queries=None,
            retrieval_gridplace=((2, 0.5), (2, 1.0), (3, 0.5), (3, 1.0)),
            retrieval_pq_m=(16, 32, 64, 128),
        )
        return replace(base, **overrides)

    def uses_torch(self) -> bool:
        return self.trainer == "torch" or (
            "timing" in self.experiments and "torch" in self.timing_trainers
        )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
