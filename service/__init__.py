"""The inference service: FastAPI + onnxruntime, a photo or a partial scan in, a patch mesh out.

Imports no torch (tests check it): bundles run in onnxruntime through :mod:`export.runtime`.
"""
