"""Service configuration: every field is also an environment variable ``GRIDPLACE_<NAME>``."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

if TYPE_CHECKING:
    from service.encoding.adaptation import AdaptationConfig


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="GRIDPLACE_", env_file=None, extra="ignore")

    host: str = Field("127.0.0.1", description="REST bind address")
    port: int = Field(8080, ge=0, le=65535, description="REST port")
    grpc_port: int = Field(50051, ge=0, le=65535, description="gRPC port (0 = disabled)")
    data_dir: Path = Field(Path("./gridplace-data"), description="registry, artifacts, uploads")
    redis_url: str | None = Field(
        None, description="redis://… to train on RQ workers; unset = embedded process pool"
    )
    queue_name: str = Field("gridplace", description="RQ queue name")
    admin_token: SecretStr | None = Field(None, description="bearer token for admin calls")
    insecure_dev: bool = Field(
        False, description="allow admin calls without a token (development only)"
    )
    max_upload_mb: int = Field(
        512, ge=1, description="largest admin upload (MiB), and the most memory its descriptors "
        "may take as float32 once decompressed",
    )  # fmt: skip
    max_retrain_mb: int = Field(
        4096, ge=1, description="most float32 descriptors (MiB) a retrain of a version's "
        "traversals gathers in memory",
    )  # fmt: skip
    max_public_body_mb: int = Field(
        16, ge=1, description="largest body of a public REST request (localize) and of a gRPC "
        "Localize message (MiB)",
    )  # fmt: skip
    max_public_requests: int = Field(
        128, ge=1, le=100_000, description="public requests in flight at once, every client "
        "together: REST calls from their headers to the end of their answer (GET, HEAD and "
        "admin calls are not counted) and gRPC Localize calls; one more is refused with 503 "
        "and Retry-After (gRPC: RESOURCE_EXHAUSTED)",
    )  # fmt: skip
    max_public_bodies_mb: int = Field(
        64, ge=1, le=1_048_576, description="MiB of body (gRPC: message) that public requests "
        "in flight hold together (a declared Content-Length is reserved before the body is "
        "read); a request that does not fit is refused the same way",
    )  # fmt: skip
    max_request_megapixels: float = Field(
        256.0, gt=0, description="most image pixels one request (or stream frame) may make the "
        "server decode, summed over its images (millions)",
    )  # fmt: skip
    max_request_work: float = Field(
        1000.0, gt=0, le=1e9, description="most work one public request may cost, in "
        "millions of units (one unit: one route frame's update in one state of the sequence "
        "filter, about 4 ns; a batch costs rows × N × 8, a drive frames × N × (filter states + "
        "8), an image 3 per pixel + 2 million); beyond: 413 before the work starts",
    )  # fmt: skip
    max_stream_frame_kb: int = Field(
        1024, ge=1, description="largest gRPC LocalizeStream message (KiB)"
    )
    grpc_workers: int = Field(
        4, ge=2, description="threads running gRPC requests' CPU work off the event loop "
        "(unary Localize calls get at most half of them; streams keep the rest)",
    )  # fmt: skip
    max_streams: int = Field(
        64, ge=1, le=100_000, description="open gRPC LocalizeStreams, every client together; "
        "one more is refused with RESOURCE_EXHAUSTED",
    )  # fmt: skip
    max_stream_vehicles: int = Field(
        8192, ge=1, le=10_000_000, description="vehicle states (a sequence filter, appearance "
        "statistics) all open streams hold together; a frame that needs one more is answered "
        "with RESOURCE_EXHAUSTED",
    )  # fmt: skip
    max_stream_state_mb: int = Field(
        1024, ge=1, le=1_048_576, description="MiB of vehicle state all open streams hold "
        "together (the filters' posteriors, the running statistics); beyond: RESOURCE_EXHAUSTED",
    )  # fmt: skip
    max_rest_vehicles: int = Field(
        10_000, ge=1, le=10_000_000, description="REST vehicles (vehicle_id + vehicle_key) whose "
        "appearance statistics the server keeps; the least recently seen are forgotten beyond",
    )  # fmt: skip
    rest_vehicle_state_mb: int = Field(
        256, ge=1, le=1_048_576, description="MiB the REST vehicles' appearance statistics hold "
        "together; the least recently seen are forgotten beyond",
    )  # fmt: skip
    train_workers: int = Field(2, ge=1, description="embedded training processes")
    job_timeout_s: int = Field(6 * 3600, ge=1, description="a training job's time limit")
    job_retries: int = Field(
        2, ge=0, le=10, description="RQ backend: how often a training part (chunk, classifier, "
        "prepare) whose worker died or that failed unexpectedly runs again before the job fails",
    )
    job_retry_backoff_s: int = Field(
        5, ge=0, le=3600, description="RQ backend: wait before the first retry of a part "
        "(doubling for each further one)",
    )
    reconcile_interval_s: float = Field(
        15.0, ge=0, description="RQ backend: how often the server checks unfinished jobs "
        "against Redis (a job that can no longer finish fails then; 0 = only when polled)",
    )
    reload_interval_s: float = Field(
        1.0, gt=0, description="how often the server checks the registry for activations"
    )
    batching: bool = Field(
        True, description="micro-batch localize requests of concurrent callers (gRPC, REST)"
    )
    batch_max_size: int = Field(256, ge=1, le=65536, description="largest micro-batch")
    batch_max_wait_ms: float = Field(
        0.0, ge=0.0, le=100.0,
        description="how long a micro-batch waits for more requests after its first (ms); "
        "requests queued while the previous batch computes join without waiting. 0 was "
        "measured best (`gridplace bench grpc --wait-grid 0,0.5,2`): 0.5 and 2 ms gained 8 "
        "streams no throughput beyond the noise of the rounds and cost a lone caller the wait",
    )
    drive_adaptation: bool = Field(
        True, description="drives (gRPC streams, /v1/localize/sequence) adapt each vehicle's "
        "frames to the running statistics of its earlier frames unless a request says "
        "otherwise (appearance adaptation; measured best across seasons, see docs/RESULTS)",
    )
    adaptation_alpha: float = Field(
        0.02, gt=0.0, le=1.0,  # service.encoding.adaptation.DEFAULT_ALPHA (a test keeps them equal)
        description="weight of the newest frame in a vehicle's running statistics",
    )
    adaptation_novelty: float = Field(
        1.0, ge=0.0, le=100.0,  # service.encoding.adaptation.DEFAULT_NOVELTY
        description="a vehicle's frame updates its running statistics only if it differs from "
        "the last one that did by this many running variances per column (0: every frame)",
    )

    condition_frames: int = Field(
        8, ge=1, le=1024,  # service.encoding.conditions.DEFAULT_INFERENCE_FRAMES
        description="an adapted drive that names no condition on a version recording "
        "conditions infers the closest one from this many first frames (then keeps it)",
    )

    def adaptation(self) -> AdaptationConfig:
        """The appearance adaptation parameters of drives served by this process."""
        from service.encoding.adaptation import AdaptationConfig

        return AdaptationConfig(alpha=self.adaptation_alpha, novelty=self.adaptation_novelty)
    serve_blas_threads: int = Field(
        1, ge=0,
        description="BLAS threads of the serving process (0 = the library's default); one "
        "thread per query batch keeps the cores for the transports and other requests",
    )
    log_level: str = Field("info", description="uvicorn / logging level")
    registry_url: str | None = Field(
        None,
        description="registry database: postgresql://user:pass@host/db for replicated servers "
        "and workers on several hosts; unset = SQLite file data_dir/registry.sqlite3",
    )
    registry_pool_size: int = Field(
        5, ge=1, le=100, description="PostgreSQL connections kept per process (as many again "
        "may open under load)",
    )
    registry_connect_timeout_s: float = Field(
        5.0, gt=0, le=60, description="how long to wait for the registry database before "
        "answering 503",
    )
    registry_journal_mode: Literal["wal", "delete"] = Field(
        "wal",
        description="SQLite registry only: wal (every process on one host) or delete (hosts "
        "sharing data_dir over a network filesystem, where WAL's shared memory fails)",
    )


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
