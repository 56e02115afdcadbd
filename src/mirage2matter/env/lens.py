"""The world's cameras as calibrated: each frame drawn through its camera's lens and principal point.

What a frame of a camera is, for ``EpisodeSpec.size`` (w, h): the camera's own image (``CameraConfig``: K, lens, its
width x height) at its full height, cropped about the image centre to the frame's aspect and scaled to h rows
(:func:`frame_camera`). For a centred pinhole (fx = fy, no skew, the principal point at the image centre, no lens)
that is the pinhole the renderers draw directly (``sim.scene.render_K``); any other camera (a real calibration's
off-centre principal point, its lens) is drawn in two steps, as the sample maker films its phone lens
(``render.lens``): the renderer draws a centred pinhole of the frame's focal length wide enough for every ray the
frame takes in, and each frame pixel reads it where its ray lands (one bilinear sample per pixel). Without this the
frames were that centred pinhole for every camera: a wide-angle wrist camera's corners tens of pixels away from what
the real camera shows there.

:func:`lens_plan` decides it once per environment; ``env.renderers.build_renderer`` builds the inner renderer (hybrid
or ground truth) for the plan's wide cameras and wraps it in :class:`LensFrames`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..render.lens import centred_K, lens_cover, resample_through_lens
from .config import EnvConfig, EnvError

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..geometry.camera import Camera
    from ..world.config import CameraConfig
    from .episode import EpisodeDraw

__all__ = ["LensFrames", "LensPlan", "frame_camera", "lens_plan"]


def frame_camera(cam: CameraConfig, width: int, height: int) -> Camera:
    """The camera whose image is a ``width`` x ``height`` frame of ``cam`` (its image at full height, cropped about
    the image centre to the frame's aspect, scaled): ``cam``'s K scaled by h / cam.height and shifted by the crop,
    its lens unchanged (the lens acts on normalised coordinates)."""
    from ..geometry.camera import Camera

    s = height / cam.height
    x0 = 0.5 * (cam.width - width / s)  # the crop's left edge, camera pixels
    K = np.asarray(cam.K, np.float64)
    K_frame = np.array([[K[0, 0] * s, K[0, 1] * s, (K[0, 2] - x0) * s], [0.0, K[1, 1] * s, K[1, 2] * s],
                        [0.0, 0.0, 1.0]])  # fmt: skip
    return Camera(K_frame, np.asarray(cam.T_mount_cam), width, height, distortion=dict(cam.distortion))


def _is_centred_pinhole(cam: Camera) -> bool:
    K = cam.K
    return (not cam.has_distortion and abs(K[0, 0] - K[1, 1]) <= 1e-9 * K[1, 1] and K[0, 1] == 0
            and abs(K[0, 2] - 0.5 * cam.width) < 1e-6 and abs(K[1, 2] - 0.5 * cam.height) < 1e-6)  # fmt: skip


@dataclass(frozen=True)
class LensPlan:
    """How an environment's frames are drawn: every camera rendered as a centred pinhole of ``render_size`` (W, H)
    (its frame's focal length), then ``rays`` [h, w, 2] (normalised pinhole coordinates of each frame pixel's ray)
    read from it for the cameras that have them; the others are the render's centre crop of the frame size."""

    size: tuple[int, int]
    render_size: tuple[int, int]
    focal: dict[str, float]
    rays: dict[str, np.ndarray]

    def render_config(self, cfg: EnvConfig) -> EnvConfig:
        """``cfg`` with every observed camera a centred pinhole of the render size and the frame's focal length."""
        world = cfg.world.copy()
        W, H = self.render_size
        for c, f in self.focal.items():
            world.cameras[c] = replace(world.cameras[c], K=centred_K(f, (W, H)), width=W, height=H, distortion={})
        return replace(cfg, world=world, episode=replace(cfg.episode, size=self.render_size))

    def frame(self, camera: str, image: np.ndarray) -> np.ndarray:
        """The frame [h, w, 3] uint8 of ``camera`` from its render [H, W, 3] uint8."""
        rays = self.rays.get(camera)
        if rays is not None:
            return resample_through_lens(image, self.focal[camera], rays, supersample=1)
        (w, h), (W, H) = self.size, self.render_size
        y0, x0 = (H - h) // 2, (W - w) // 2
        return np.ascontiguousarray(image[y0 : y0 + h, x0 : x0 + w])


def lens_plan(cfg: EnvConfig) -> LensPlan | None:
    """The plan for ``cfg``'s observed cameras, or None when every one is a centred pinhole (the renderers draw its
    frames directly). EnvError naming the camera when a lens sees too wide for a pinhole render."""
    w, h = cfg.size
    frames = {c: frame_camera(cfg.world.cameras[c], w, h) for c in cfg.cameras}
    if all(_is_centred_pinhole(f) for f in frames.values()):
        return None
    focal = {c: float(f.K[1, 1]) for c, f in frames.items()}
    rays, W, H = {}, w, h
    for c, f in frames.items():
        if _is_centred_pinhole(f):
            continue
        try:
            rays[c], (cw, ch) = lens_cover(f, focal[c])
        except ValueError as e:
            raise EnvError(
                f"camera {c!r}: its lens ({f.distortion_model}, {f.distortion_json()}) {e}; give the world a "
                "camera undistorted to a pinhole (world.yaml cameras.<name>: no distortion, its K), or a narrower crop"
            ) from None
        W, H = max(W, cw), max(H, ch)
    return LensPlan((w, h), (W, H), focal, rays)


class LensFrames:
    """A renderer drawing ``plan``'s wide pinholes (``inner``), its frames resampled through each camera's lens."""

    def __init__(self, inner: Any, plan: LensPlan) -> None:
        self.inner, self.plan = inner, plan

    @property
    def timings(self) -> dict[str, float]:
        return self.inner.timings

    def start_episode(self, draw: EpisodeDraw) -> None:
        self.inner.start_episode(draw)

    def render(self) -> dict[str, np.ndarray]:
        return {c: self.plan.frame(c, im) for c, im in self.inner.render().items()}

    def close(self) -> None:
        self.inner.close()

    @staticmethod
    def like(renderer: Any, size: tuple[int, int], make: Callable[[tuple[int, int]], Any]) -> Any:
        """Another renderer of the same twin drawn as ``renderer`` draws (``make(render size)``): through the same
        plan when ``renderer`` is a :class:`LensFrames`, else at ``size``."""
        if isinstance(renderer, LensFrames):
            return LensFrames(make(renderer.plan.render_size), renderer.plan)
        return make(size)
