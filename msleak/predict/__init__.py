"""Predict beam-corrupted visibilities of a point-source sky into a Measurement Set.

``kernels`` holds the pure numba/BLAS measurement-equation kernels, ``stations`` the
per-station coordinates fitted to the MS's UVW, ``sky`` the preparation of sky sources,
``engine`` the chunked run that reads, predicts and writes (docs/science.md section 4).
"""

from msleak.predict.engine import DEFAULT_MEMORY_LIMIT, PredictResult, predict

__all__ = ["predict", "PredictResult", "DEFAULT_MEMORY_LIMIT"]
