"""gRPC API of the model server: ``gridplace.v1.Localization`` in ``protos/``.

The server (:mod:`service.grpc.server`) runs inside ``gridplace serve`` beside REST over the same
service layer; the Python stubs under :mod:`service.grpc.gen` are generated from ``protos/`` by
``python -m service.grpc.codegen`` and a test fails when they drift from the ``.proto``.
"""
