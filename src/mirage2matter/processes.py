"""Child processes that do not outlive their parent (generation's workers, the splat server)."""

from __future__ import annotations

__all__ = ["die_with_parent"]


def die_with_parent() -> None:
    """Linux: SIGKILL this process when its parent dies (a killed generator must not leave workers or a renderer
    behind that would keep committing attempts, or holding a GPU, next to the rerun). Elsewhere: nothing."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
