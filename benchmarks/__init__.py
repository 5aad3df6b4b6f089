"""Benchmark scripts: ``python -m benchmarks.reproduce_paper``, ``benchmarks.speed``, ...

BLAS is limited to one thread here, before numpy is imported: the matrix products of these
benchmarks are small, and OpenBLAS's thread start-up would dominate them (and fight with the
other processes of a shared 2-core machine). Set ``OPENBLAS_NUM_THREADS`` yourself to override.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
