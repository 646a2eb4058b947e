"""The REST API (FastAPI): ``create_app(settings)``; run it with ``gridplace serve``."""

from service.api.app import create_app

__all__ = ["create_app"]
