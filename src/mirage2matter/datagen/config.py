"""Settings of demonstration generation from the simulated world (no heavy imports: the command line and
the stages read them before anything is built)."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..env.config import (
    EpisodeSpec,
    HybridOptions,
    Randomization,  # the environment's: generation draws its episodes through it
)
from ..errors import M2MError
from .dataset import RunConfig

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
    sha1      the policies' weight files' contents: the dataset's fingerprint (a retrained policy is another
              dataset, a moved one the same)
    opener    (policy folders, device) -> the policy (an ensemble for several): the policy package's, handed in
              by the stage (generation runs policies, it does not know how they are stored)
    """

    policies: tuple[str, ...]
    steps: tuple[int, int] = (5, 35)
    sha1: tuple[str, ...] = ()
    opener: Callable[[Sequence[str], str], Any] | None = field(default=None, compare=False, repr=False)

    @classmethod
    def of(cls, policy_files: list[Path], steps: tuple[int, int], opener: Callable[[Sequence[str], str], Any]
           ) -> Takeover:  # fmt: skip
        """The takeover by the finished policies whose weight files are ``policy_files`` (one per policy folder)."""
        sha = tuple(hashlib.sha1(Path(f).read_bytes()).hexdigest() for f in policy_files)
        return cls(tuple(str(Path(f).parent) for f in policy_files), (int(steps[0]), int(steps[1])), sha, opener)

    def problems(self) -> list[str]:
        if not self.policies:
            return ["takeover names no policy"]
        bad = takeover_steps_problem(self.steps)
        return [bad] if bad else []

    def open(self, device: str = "cpu") -> Any:
        """The policy (an ensemble for several), on ``device``."""
        if self.opener is None:
            raise M2MError("takeover: no policy opener was given (Takeover.of(..., opener=...))")
        return self.opener(self.policies, device)

    def to_json(self) -> dict[str, Any]:
        """What the dataset depends on: the policies' contents and the steps (not where the policies lie)."""
        return {"steps": list(self.steps), "sha1": list(self.sha1)}


@dataclass(frozen=True)
class GenerateConfig:
    """Generation's settings, by section (the world, the task and the output folder are ``generate``'s arguments);
    the generate stage's Config builds it, each section the library that uses it takes as it is.

    run            how many episodes and how they are run and written (count, seed, workers, Ray, format, preview)
    episode        what the frames are: size, rate, cameras (the environment's :class:`EpisodeSpec`)
    randomization  per-episode camera-mount and colour jitter, random object start poses
    hybrid         the hybrid renderer: how objects and the robot are drawn, the splat layer's supersampling
                   (``env.config.hybrid_options``)
    splat_server   draw every worker's splat layer in one process, batched (``render.splat_server``): for a GPU,
                   where one batched gsplat call serves all the workers' episodes; the same episodes, every camera
                   drawn whole (not over a cached background); local worker processes only (not with Ray)
    takeover       None: the expert acts from each episode's start; a :class:`Takeover`: a trained policy acts
                   first and the expert takes over from where it left the world
    ground_truth   None: hybrid frames; a sample folder: its ground-truth renderer draws the frames instead (the
                   sim-to-real bench's oracle: demonstrations in the "real world"'s own pictures)
    """

    run: RunConfig
    episode: EpisodeSpec = field(default_factory=EpisodeSpec)
    randomization: Randomization = field(default_factory=Randomization)
    hybrid: HybridOptions = field(default_factory=HybridOptions)
    splat_server: bool = False
    takeover: Takeover | None = None
    ground_truth: Path | None = None
