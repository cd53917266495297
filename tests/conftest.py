"""Test-wide settings: one BLAS/torch thread per worker (CI runs `pytest -n 2` on 2 cores)."""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
