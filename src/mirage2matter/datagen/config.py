"""Settings of demonstration generation from the simulated world (no heavy imports: the command line and
the stages read them before anything is built)."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["GenerateConfig", "Randomization"]


@dataclass(frozen=True)
class Randomization:
    """Half-ranges of the per-episode jitter (0 disables one). Object start poses follow the world's
    ``randomize`` region (world.yaml).

    camera_deg  rotation (degrees) of each camera mount about a random axis
    camera_m    translation (m) of each camera mount
    brightness  brightness jitter of the splat world
    contrast    contrast jitter of the splat world
    gain        per-channel light colour jitter
    objects     random object start poses (False: the world's placements)
    """

    camera_deg: float = 0.5
    camera_m: float = 0.005
    brightness: float = 0.06
    contrast: float = 0.08
    gain: float = 0.05
    objects: bool = True


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
