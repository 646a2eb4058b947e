"""Python stubs generated from ``protos/gridplace/v1/*.proto``. DO NOT EDIT: run
``python -m service.grpc.codegen`` after changing a ``.proto`` (``--check`` verifies them; the
test suite runs that check, so stale stubs cannot land)."""
