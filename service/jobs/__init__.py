"""Training jobs: the backend interface, the embedded process pool and RQ workers.

>>> backend = make_backend(settings, registry)   # RQ if settings.redis_url, else embedded
>>> job = backend.submit("route-a", route_npy, ModelParams.parse(n_chunks=4), None, "key-1")
>>> backend.get_job(job.id).state                 # queued → running → succeeded | failed
"""

from service.jobs.backend import TrainingBackend, make_backend

__all__ = ["TrainingBackend", "make_backend"]
