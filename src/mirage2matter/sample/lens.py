"""The sample maker's video lenses (``m2m sample make --lens NAME``): a phone-like lens the video is filmed through
(``render.lens`` resamples the renderer's pinhole through it)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera

__all__ = ["LENSES", "LensConfig"]


@dataclass(frozen=True)
class LensConfig:
    """A video camera's intrinsics and lens (pixels at the sample's image size; pixel centres at +0.5).

    name            what the sample's command line calls it (``m2m sample make --lens NAME``)
    fx, fy          focal lengths (px)
    cx, cy          principal point (px)
    distortion      OpenCV radial-tangential coefficients (k1, k2, p1, p2, k3)
    """

    name: str
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float]

    def camera(self, width: int, height: int) -> Camera:
        """The lens as a :class:`Camera` of ``width`` x ``height`` (pose: identity)."""
        k1, k2, p1, p2, k3 = self.distortion
        K = np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])
        return Camera(K, np.eye(4), width, height, self.name, {"k1": k1, "k2": k2, "p1": p1, "p2": p2, "k3": k3})


LENSES: dict[str, LensConfig | None] = {
    "pinhole": None,  # the renderer's own camera: no distortion, principal point at the centre (the bundled sample)
    # A phone's main camera at 640x480 (video mode, ~69 deg across with the lens): barrel distortion (k1 < 0, the
    # image corners ~35 px inside where a pinhole puts them), a principal point 4.6 / 3.1 px off the centre, fx and fy
    # 0.1 % apart, and the small decentring (p1, p2) of a real lens assembly; sizes as phone calibrations report them.
    "phone": LensConfig("phone", fx=497.3, fy=497.8, cx=324.6, cy=236.9,
                        distortion=(-0.16, 0.07, 0.0009, -0.0006, 0.0)),
}
