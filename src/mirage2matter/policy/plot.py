"""The loss-curve PNG, drawn with PIL (matplotlib is only here as a dependency of Genesis' vtk, so the
package does not rely on it)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..atomic import atomic_path

__all__ = ["plot_loss_curve", "smooth"]

_COLOURS = [(160, 190, 225), (31, 90, 170), (214, 39, 40), (44, 160, 44)]


def smooth(y: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average of y [n] over ``window`` points (narrower at the ends, so no lag), [n]."""
    y = np.asarray(y, np.float64)
    if window <= 1 or y.size == 0:
        return y
    c = np.concatenate([[0.0], np.cumsum(y)])
    i = np.arange(y.size)
    half = np.minimum(np.minimum(window // 2, i), y.size - 1 - i)  # symmetric, shrinking near both ends
    return (c[i + half + 1] - c[i - half]) / (2 * half + 1)


def plot_loss_curve(
    path: str | Path,
    series: Sequence[tuple[str, np.ndarray, np.ndarray]],
    title: str = "",
    size: tuple[int, int] = (800, 480),
) -> None:
    """Write a PNG of curves ``(label, steps [n], values [n])`` on a log-scale y axis, atomically."""
    from PIL import Image, ImageDraw, ImageFont

    w, h = size
    left, right, top, bottom = 70, 20, 36, 44
    im = Image.new("RGB", size, (255, 255, 255))
    d = ImageDraw.Draw(im)
    font = ImageFont.load_default()
    series = [(n, np.asarray(x, np.float64), np.asarray(y, np.float64)) for n, x, y in series]
    series = [(n, x[(y > 0) & np.isfinite(y)], y[(y > 0) & np.isfinite(y)]) for n, x, y in series]
    pts = [s for s in series if s[1].size]
    x0, x1 = (min(s[1].min() for s in pts), max(s[1].max() for s in pts)) if pts else (0.0, 1.0)
    y0, y1 = (min(s[2].min() for s in pts), max(s[2].max() for s in pts)) if pts else (0.1, 1.0)
    x1 = max(x1, x0 + 1)
    ly0, ly1 = math.floor(math.log10(y0) * 4) / 4, math.ceil(math.log10(y1) * 4) / 4  # quarter decades
    ly1 = max(ly1, ly0 + 0.25)

    def px(x: np.ndarray, y: np.ndarray) -> list[tuple[float, float]]:
        u = left + (x - x0) / (x1 - x0) * (w - left - right)
        v = h - bottom - (np.log10(y) - ly0) / (ly1 - ly0) * (h - top - bottom)
        return list(zip(u.tolist(), v.tolist(), strict=True))

    d.rectangle([left, top, w - right, h - bottom], outline=(0, 0, 0))
    for e in np.arange(math.floor(ly0), math.floor(ly1) + 1):
        for m in (1, 2, 5):
            val = m * 10.0**e
            if 10**ly0 <= val <= 10**ly1:
                _, v = px(np.array([x0]), np.array([val]))[0]
                d.line([left, v, w - right, v], fill=(225, 225, 225))
                d.text((4, v - 6), f"{val:g}", fill=(0, 0, 0), font=font)
    for i in range(6):
        x = x0 + (x1 - x0) * i / 5
        u, _ = px(np.array([x]), np.array([10**ly0]))[0]
        d.line([u, h - bottom, u, h - bottom + 4], fill=(0, 0, 0))
        d.text((u - 12, h - bottom + 8), f"{x:.0f}", fill=(0, 0, 0), font=font)
    d.text((w // 2 - 12, h - 18), "step", fill=(0, 0, 0), font=font)
    d.text((left, 10), title, fill=(0, 0, 0), font=font)
    for k, (name, x, y) in enumerate(series):
        col = _COLOURS[k % len(_COLOURS)]
        if x.size > 1:
            d.line(px(x, y), fill=col, width=2)
        elif x.size == 1:
            (u, v), = px(x, y)
            d.ellipse([u - 3, v - 3, u + 3, v + 3], fill=col)
        d.text((w - right - 150, top + 8 + 14 * k), f"-- {name}", fill=col, font=font)
    path = Path(path)
    with atomic_path(path) as tmp:
        im.save(tmp, format="PNG")
