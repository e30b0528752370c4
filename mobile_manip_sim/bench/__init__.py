"""`bench`: what accuracy costs in computing time, how the dynamics scale, how we compare with
Pinocchio, and how hard cases behave — written to ``REPORT.md`` with PNG plots.

Times are measured on one core: the BLAS thread pools are pinned to one thread before numpy is
first imported (they would otherwise spin on the second core and distort both our runs and the
peers'), and every figure is the CPU time of this thread, best of several repeats.
"""
import os

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")
