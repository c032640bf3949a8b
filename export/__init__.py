"""Export trained models to ONNX bundles and run them with onnxruntime, without torch.

:mod:`export.bundle` (the bundle format, its verification) and :mod:`export.runtime` (onnxruntime
sessions, the decoder steps) import no torch; :mod:`export.graphs` and :mod:`export.fold` (the
export itself) do.
"""
