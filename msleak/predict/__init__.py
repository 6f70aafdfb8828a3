"""Predict beam-corrupted visibilities of a point-source sky into a Measurement Set.

``kernels`` holds the pure numba/BLAS measurement-equation kernels, ``stations`` the
per-station coordinates fitted to the MS's UVW, ``components`` the preparation of sky
sources, ``plan`` the checks and plan of a run, ``chunks`` the time-chunk tasks,
``runstate`` the column writes and resumable run state, ``engine`` the verb
:func:`predict` (docs/predict.md, docs/science.md section 4).
"""

from msleak._callable import make_callable
from msleak.predict.engine import predict
from msleak.predict.plan import PredictResult

__all__ = ["predict", "PredictResult"]

make_callable(__name__, predict)
