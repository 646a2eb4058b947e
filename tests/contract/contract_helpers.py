"""Constants of the API contract tests (a uniquely named module, beside conftest.py)."""

from __future__ import annotations

TOKEN = "contract-tests-admin-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
N, D = 160, 24  # the SYNTHETIC route served as map "route"
ENV = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_MAX_UPLOAD_MB": "1",
       "GRIDPLACE_RELOAD_INTERVAL_S": "0.1", "GRIDPLACE_TRAIN_WORKERS": "1",
       "GRIDPLACE_LOG_LEVEL": "info"}  # fmt: skip
