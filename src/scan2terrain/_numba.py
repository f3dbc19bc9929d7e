"""numba, readied for the kernels without the scipy import its BLAS probe makes.

When numba first compiles a function or loads one from its cache, it imports its numpy support
(``numba.np.arraymath``), whose import probes for BLAS by importing ``scipy.linalg``: 80 ms of
every process that runs a kernel, and none of our kernels calls BLAS (no ``np.dot``, ``@`` or
``np.linalg``). Every kernel module imports this one first: it imports that numpy support with
``scipy.linalg`` unimportable for the moment, so numba records "no BLAS" (it then uses its own
inner product in ``np.correlate``/``np.convolve``, which we do not use either, and ``np.dot``
would still import scipy when compiled). A process that has imported ``scipy.linalg`` already
is left as it is.
"""

from __future__ import annotations

import os
import sys

# OpenMP's threads spin-wait between parallel regions by default (GNU OpenMP: some 300,000
# spins). With another process on the other core, the waiting thread keeps its core busy while
# the one it waits for is descheduled: FR-079 at 0.05 m took 84 ms on two threads against 53 on
# one. Passive waits (a futex) cost nothing measurable on an idle machine (43 against 46 ms)
# and bring the loaded case to 53 ms. Set before OpenMP loads (numba's first parallel call),
# unless the user chose a policy; child processes (Dask workers) inherit it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# numba imports coverage.py, where it is installed, to report the lines it compiles to a
# coverage run in progress: 40 ms of every process that runs a kernel (a third of numba's own
# import). A run in progress has imported coverage already (coverage run, pytest-cov) and is
# left as it is; otherwise numba is imported with coverage unimportable for the moment.
_COVERAGE = "coverage"
_hidden = _COVERAGE not in sys.modules
if _hidden:
    sys.modules[_COVERAGE] = None  # type: ignore[assignment]  # `import coverage` fails now
try:
    import numba
finally:
    if _hidden and sys.modules.get(_COVERAGE, _COVERAGE) is None:
        del sys.modules[_COVERAGE]

# numba tries TBB first; Open3D's wheel ships an older libtbb, and once Open3D is loaded numba
# finds that one, warns and falls back. OpenMP (then numba's own work queue) unless the user
# chose a threading layer.
if not any(k.startswith("NUMBA_THREADING_LAYER") for k in os.environ):
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]  # type: ignore[attr-defined]

__all__ = ["numba"]

_PROBED = "scipy.linalg"


def _numpy_support_without_blas_probe() -> None:
    if "numba.np.arraymath" in sys.modules or _PROBED in sys.modules:
        return
    sys.modules[_PROBED] = None  # type: ignore[assignment]  # `import scipy.linalg` fails now
    try:
        # Imported for its side effect, here: its BLAS probe runs, and finds none.
        import numba.np.arraymath  # noqa: F401, PLC0415
    finally:
        if sys.modules.get(_PROBED, _PROBED) is None:
            del sys.modules[_PROBED]


_numpy_support_without_blas_probe()
