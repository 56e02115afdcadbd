"""Mirage2Matter: multi-view video of a robot workspace -> photorealistic, physically grounded simulator."""

import os as _os

# torch's idle OpenMP workers spin and starve numba on a 2-core machine unless told to sleep;
# this must be set before torch is first imported (FIELD_NOTES.md, "Threads").
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
_os.environ.setdefault("NUMBA_CACHE_DIR", _os.path.join(_os.path.expanduser("~"), ".cache", "mirage2matter", "numba"))

__version__ = "0.1.0"


def configure_threads(n: int | None = None) -> int:
    """Give torch and numba the same thread count (default: all cores). Returns it."""
    import numba
    import torch

    n = n or _os.cpu_count() or 1
    n = min(n, numba.config.NUMBA_NUM_THREADS)
    torch.set_num_threads(n)
    numba.set_num_threads(n)
    return n
