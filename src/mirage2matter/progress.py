"""Progress of long loops (training, generation, evaluation) that reads well on a terminal and in a log.

On a terminal a tqdm bar redraws itself in place. Anywhere else (CI, ``nohup``, ``m2m run > log 2>&1``) each
redraw is a ``\\r`` and the next, so a log gets one line of thousands of updates (a 6-minute scene wrote one
55 kB line). :func:`progress_bar` is the one place that chooses: a tqdm bar when its stream is a terminal, else
a :class:`LineProgress`, which writes a plain line when it starts, at most every ``interval`` seconds (and at
each tenth of a known total) while it runs, and once more when it ends. Both take the same calls (iterate,
``update``, ``set_postfix``, ``set_postfix_str``, ``close``, ``n``), so a loop does not know which it has.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import IO, Any

__all__ = ["INTERVAL_S", "MAX_LINE", "LineProgress", "is_terminal", "progress_bar"]

INTERVAL_S = 10.0  # seconds between two progress lines in a log
MAX_LINE = 200  # characters; a longer progress line (a long postfix) is cut


def is_terminal(stream: Any) -> bool:
    """Whether ``stream`` is an interactive terminal (False for files, pipes, closed or odd streams)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


def progress_bar(
    iterable: Iterable | None = None,
    *,
    total: float | None = None,
    desc: str = "",
    unit: str = "it",
    initial: float = 0,
    disable: bool = False,
    leave: bool = True,
    file: IO[str] | None = None,
    interval: float = INTERVAL_S,
    **tty_options: Any,
) -> Any:
    """A progress bar over ``iterable`` (or updated by hand up to ``total``) written to ``file`` (default stderr).

    On a terminal: ``tqdm(iterable, total=..., desc=..., unit=..., initial=..., leave=..., **tty_options)``
    (``tty_options``: tqdm's own, e.g. ``dynamic_ncols=True``). Otherwise: a :class:`LineProgress` with the same
    calls. ``disable``: nothing is written either way."""
    stream = sys.stderr if file is None else file
    if disable or not is_terminal(stream):
        return LineProgress(iterable, total=total, desc=desc, unit=unit, initial=initial, file=stream,
                            interval=interval, disable=disable)  # fmt: skip
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, initial=initial, leave=leave, file=stream, **tty_options)


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    h, m = divmod(s // 60, 60)
    return f"{h}:{m:02d}:{s % 60:02d}" if h else f"{m}:{s % 60:02d}"


def _number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:.4g}"


class LineProgress:
    """Progress as plain lines, for a stream that is not a terminal (see the module's doc).

    A line: ``desc: n/total unit (pct %), elapsed, ~left, rate, postfix`` (without total: ``desc: n unit, ...``),
    written when the bar starts, when ``interval`` seconds have passed since the last line or the count crossed
    a tenth of ``total``, and when it closes (if the count moved since the last line); never longer than
    :data:`MAX_LINE`, never a ``\\r``.
    """

    def __init__(
        self,
        iterable: Iterable | None = None,
        total: float | None = None,
        desc: str = "",
        unit: str = "it",
        initial: float = 0,
        file: IO[str] | None = None,
        interval: float = INTERVAL_S,
        disable: bool = False,
    ) -> None:
        if total is None and iterable is not None:
            try:
                total = len(iterable)  # type: ignore[arg-type]
            except TypeError:
                total = None
        self.iterable, self.total, self.desc, self.unit = iterable, total, desc or "", unit
        self.n = self.initial = initial
        self.file = sys.stderr if file is None else file
        self.interval, self.disable = interval, disable
        self.postfix = ""
        self.start_t = self.last_t = time.monotonic()
        self.last_n: float | None = None
        self.closed = False
        self._write()

    # ---- what a loop calls -------------------------------------------------------------------------------
    def __iter__(self) -> Iterator:
        if self.iterable is None:
            raise TypeError("LineProgress: nothing to iterate (made without an iterable)")
        try:
            for item in self.iterable:
                yield item
                self.update(1)
        finally:
            self.close()

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def update(self, n: float = 1) -> None:
        self.n += n
        if self._due():
            self._write()

    def set_postfix(self, ordered_dict: dict | None = None, refresh: bool = True, **kwargs: Any) -> None:
        """``k=v, ...`` after the figures of the next line (``refresh`` is tqdm's; lines keep their schedule)."""
        items = {**(ordered_dict or {}), **kwargs}
        self.postfix = ", ".join(f"{k}={_number(v) if isinstance(v, float) else v}" for k, v in items.items())

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self.postfix = str(s)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self.n != self.last_n:
            self._write(final=True)

    # ---- the lines -------------------------------------------------------------------------------------
    def _tenth(self, n: float) -> int:
        return int(10 * n // self.total) if self.total else 0

    def _due(self) -> bool:
        if self.closed:
            return False
        if time.monotonic() - self.last_t >= self.interval:
            return True
        return bool(self.total) and self.last_n is not None and self._tenth(self.n) > self._tenth(self.last_n)

    def line(self, final: bool = False) -> str:
        """The progress line for now (without a newline)."""
        elapsed = time.monotonic() - self.start_t
        head = f"{self.desc}: " if self.desc else ""
        if self.total:
            parts = [f"{head}{_number(self.n)}/{_number(self.total)} {self.unit} ({100 * self.n / self.total:.0f} %)"]
        else:
            parts = [f"{head}{_number(self.n)} {self.unit}"]
        parts.append(f"{_clock(elapsed)} elapsed")
        done = self.n - self.initial
        if done > 0 and elapsed > 0:
            rate = done / elapsed
            if self.total and not final and self.n < self.total:
                parts.append(f"~{_clock((self.total - self.n) / rate)} left")
            parts.append(f"{rate:.3g} {self.unit}/s" if rate >= 1 else f"{1 / rate:.3g} s/{self.unit}")
        if self.postfix:
            parts.append(self.postfix)
        text = ", ".join(parts).replace("\r", " ").replace("\n", " ")
        return text if len(text) <= MAX_LINE else text[: MAX_LINE - 3] + "..."

    def _write(self, final: bool = False) -> None:
        self.last_t, self.last_n = time.monotonic(), self.n
        if self.disable:
            return
        try:
            self.file.write(self.line(final) + "\n")
            self.file.flush()
        except (ValueError, OSError):  # a closed stream: progress is not worth failing the work for
            pass
