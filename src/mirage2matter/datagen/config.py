"""Settings of demonstration generation from the simulated world (no heavy imports: the command line and
the stages read them before anything is built)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..env.config import Randomization  # the environment's: generation draws its episodes through it

__all__ = ["GenerateConfig", "Randomization", "Takeover"]

MAX_TAKEOVER_STEPS = 10_000


def takeover_steps_problem(steps: tuple[int, int]) -> str | None:
    """What is wrong with a takeover's (lo, hi) step range, or None (one check for the stage and the generator)."""
    lo, hi = steps
    if 0 <= lo <= hi <= MAX_TAKEOVER_STEPS:
        return None
    return (f"takeover_steps must be lo,hi with 0 <= lo <= hi <= {MAX_TAKEOVER_STEPS} (control ticks the policy acts "
            f"before the expert takes over), got {lo},{hi}")  # fmt: skip


@dataclass(frozen=True)
class Takeover:
    """A trained policy acts first in every episode, then the scripted expert takes over from wherever the policy
    left the robot and the objects; the episode is recorded from the takeover on (the policy's own steps are not
    demonstrations). The states a policy drives the world into, labelled by the expert: DAgger's data (Ross et
    al. 2011) with the expert taking over rather than labelling every state, since ours plans whole motions.

    policies  the trained policies' folders (two or more: run as one ensemble, their chunks averaged)
    steps     (lo, hi): the policy acts for a number of control ticks drawn uniformly in [lo, hi] per episode (from
              the episode's seed, so a seed is one episode)
    sha1      the policies' ``policy.pt`` contents: the dataset's fingerprint (a retrained policy is another dataset,
              a moved one the same)
    """

    policies: tuple[str, ...]
    steps: tuple[int, int] = (5, 35)
    sha1: tuple[str, ...] = ()

    @classmethod
    def of(cls, policy_dirs: list[Path], steps: tuple[int, int]) -> Takeover:
        """The takeover by the policies in ``policy_dirs`` (each holding a finished ``policy.pt``)."""
        from ..policy.config import POLICY_FILE

        sha = tuple(hashlib.sha1((Path(d) / POLICY_FILE).read_bytes()).hexdigest() for d in policy_dirs)
        return cls(tuple(str(d) for d in policy_dirs), (int(steps[0]), int(steps[1])), sha)

    def problems(self) -> list[str]:
        if not self.policies:
            return ["takeover names no policy"]
        bad = takeover_steps_problem(self.steps)
        return [bad] if bad else []

    def open(self, device: str = "cpu") -> Any:
        """The policy (an ensemble for several), on ``device``."""
        from ..policy import load_ensemble, load_policy

        if len(self.policies) == 1:
            return load_policy(self.policies[0], device=device)
        return load_ensemble(self.policies, device=device)

    def to_json(self) -> dict[str, Any]:
        """What the dataset depends on: the policies' contents and the steps (not where the policies lie)."""
        return {"steps": list(self.steps), "sha1": list(self.sha1)}


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
    robot_look     how the robot is drawn (``env.config.HybridOptions.robot_look``): "auto", "gaussians", "mesh"
    takeover       None: the expert acts from each episode's start; a :class:`Takeover`: a trained policy acts
                   first and the expert takes over from where it left the world
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
    robot_look: str = "auto"
    takeover: Takeover | None = None
