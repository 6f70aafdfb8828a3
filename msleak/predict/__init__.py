"""The numerics of predict: beam-corrupted visibilities of sky components.

``kernels`` holds the pure numba/BLAS measurement-equation kernels, ``stations`` the
per-station coordinates fitted to the MS's UVW, ``baselines`` the rows summed from their own
UVW, ``components`` the preparation of sky sources, ``gridsky`` and ``idg`` the image-domain
degridder and its accuracy contract, ``chunks`` one time chunk's visibilities, ``options``
the typed options. The verb :func:`msleak.predict` reads the MS and writes the columns
(:mod:`msleak.verbs.predict`); this package is callable as that verb (docs/predict.md,
docs/science.md section 4).
"""

from msleak._callable import make_callable

make_callable(__name__, "msleak.verbs.predict:predict")
