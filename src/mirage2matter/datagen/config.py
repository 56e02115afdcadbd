"""Settings of demonstration generation from the simulated world (no heavy imports: the command line and
the stages read them before anything is built)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..env.config import Randomization  # the environment's: generation draws its episodes through it

__all__ = ["GenerateConfig", "Randomization"]


@dataclass(frozen=True)
class GenerateConfig:
    """How many demonstrations, how they are run and what their frames are (the world, the task and the output
    folder are ``generate``'s arguments).

    episodes       successful episodes wanted
    workers        parallel workers (processes, or Ray actors with ``ray_address``)
    ray_address    None: local processes; "local": a private Ray instance; "auto" / "host:port": a cluster
    format         dataset format: "lerobot-v3.0" or "lerobot-v2.1"
    seed           run seed: same seed, same episodes
    size           (width, height) of every camera's frames
    fps            control and video rate
    cameras        which world cameras become videos
    max_attempts   give up after this many attempts (None: 3 * episodes + 5)
    preview        episodes shown in preview.mp4 / contact_sheet.png (0: none)
    randomization  per-episode camera-mount and colour jitter, random object start poses
    objects        how objects are drawn: "gaussians" (the method) or "meshes" (the mesh-only ablation)
    splat_server   draw every worker's splat layer in one process, batched (``render.splat_server``): for a GPU,
                   where one batched gsplat call serves all the workers' episodes; the same episodes, every camera
                   drawn whole (not over a cached background); local worker processes only (not with Ray)
    supersample    the splat layer drawn at s x the frame size and box-averaged down (``SplatRenderOptions``):
                   objects far smaller than the frame's pixels keep their true area (~s^2 the splat time)
    """

    episodes: int
    workers: int = 1
    ray_address: str | None = None
    format: str = "lerobot-v3.0"
    seed: int = 0
    size: tuple[int, int] = (224, 224)
    fps: int = 10
    cameras: tuple[str, ...] = ("head", "wrist")
    max_attempts: int | None = None
    preview: int = 4
    randomization: Randomization = field(default_factory=Randomization)
    objects: str = "gaussians"
    splat_server: bool = False
    supersample: int = 1
