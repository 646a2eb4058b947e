"""The service layer shared by every transport: model store, localization, uploads, metrics."""

from service.core.localization import LocalizationService, LocalizeResult
from service.core.metrics import ServiceMetrics
from service.core.model_store import LoadedModel, ModelStore

__all__ = ["LoadedModel", "LocalizationService", "LocalizeResult", "ModelStore", "ServiceMetrics"]
