"""Settings of a twin environment (and of a generated episode, which is an environment episode with the scripted
expert acting): the per-episode randomisation, the hybrid renderer's knobs, the whole configuration.

No heavy imports (no torch, no Genesis): the command line and ``datagen.config`` read these before anything is
built.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import M2MError

if TYPE_CHECKING:
    from ..render.splat_world import SplatRenderOptions
    from ..sim.tasks import Task
    from ..world.config import WorldConfig

__all__ = ["CAMERAS", "GROUND_TRUTH_TEXTURE_FILTER", "EnvConfig", "EnvError", "EpisodeSpec", "HybridOptions",
           "Randomization", "check_config", "parse_start_region"]  # fmt: skip

CAMERAS = ("head", "wrist")
# How the env's ground-truth frames filter the sample's textures (env.ground_truth.GroundTruthFrames): trilinearly,
# not anisotropically as its video was rendered (llvmpipe's anisotropic filter held single frames for minutes). Frames
# drawn before 2026-12-06 were anisotropic: what records them (a dataset's fingerprint, policy-gap's cache) names it.
GROUND_TRUTH_TEXTURE_FILTER = "trilinear"


@dataclass(frozen=True)
class EpisodeSpec:
    """What an episode's frames are: the one owner of the frame size, the rate and the cameras. The environment,
    generation (its datasets' spec), the evaluation and the benchmarks take it, or refer to its defaults.

    size     (width, height) of every camera's frames, pixels
    fps      control and video rate (Hz): one action and one frame per control tick
    cameras  which world cameras are observed (``observation.images.<camera>``) and recorded
    """

    size: tuple[int, int] = (224, 224)
    fps: int = 10
    cameras: tuple[str, ...] = CAMERAS


class EnvError(M2MError, ValueError):
    """Bad environment input (a world without the cameras, an unknown renderer, an action of the wrong size);
    the message says what was wrong and what to do."""


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
    object_shrink  the objects' Gaussians drawn at a random scale in [1 - object_shrink, 1] about their base, one per
                episode (their physics unchanged): a policy that does not rely on a reconstruction's apparent size
                (the sample's reconstructed objects cover 1.2-1.8x their true area in the head camera's view)
    table_texture  the table's Gaussians re-coloured per episode: evened out towards their mean colour (up to 2t), a
                per-channel gain in [1 - t, 1 + t] and a random grain field of amplitude up to t
                (``env.table_texture``; 0: the reconstruction's own table)
    start_regions  boxes (name, x_min, x_max, y_min, y_max), base frame, m: each named object starts with its centre
                inside one of its boxes - the layout is drawn as usual and redrawn until it does, so the other objects
                keep their usual spread around it. Targeted data where a policy fails (the corners of the region);
                () : the whole world ``randomize`` region
    """

    camera_deg: float = 0.5
    camera_m: float = 0.005
    brightness: float = 0.06
    contrast: float = 0.08
    gain: float = 0.05
    objects: bool = True
    object_shrink: float = 0.0
    table_texture: float = 0.0
    start_regions: tuple[tuple[str, float, float, float, float], ...] = ()

    def regions(self) -> dict[str, list[tuple[float, float, float, float]]]:
        """``start_regions`` by object: {name: [(x_min, x_max, y_min, y_max), ...]}."""
        out: dict[str, list[tuple[float, float, float, float]]] = {}
        for name, *box in self.start_regions:
            out.setdefault(name, []).append(tuple(float(v) for v in box))
        return out


def parse_start_region(text: str) -> tuple[str, float, float, float, float]:
    """``"banana:0.55,0.62,-0.3,-0.2"`` -> ("banana", 0.55, 0.62, -0.3, -0.2) (x_min, x_max, y_min, y_max in m)."""
    name, sep, rest = str(text).partition(":")
    try:
        box = [float(v) for v in rest.split(",")]
    except ValueError:
        box = []
    if not sep or not name.strip() or len(box) != 4:
        raise EnvError(f"start region {text!r}: write it as object:x_min,x_max,y_min,y_max in metres (base frame), "
                       'e.g. "banana:0.55,0.62,-0.3,-0.2"')  # fmt: skip
    return (name.strip(), *box)


def _fast_splats() -> SplatRenderOptions:
    # Measured on a wrist-camera episode of the reconstructed sample world at 224 px: SH band 1 instead of 3 is
    # 43.5 dB from the full render and poses a part 2.4x faster; dropping Gaussians below opacity 0.02 (most
    # of an object reconstruction's are fainter) is 40 dB from it and renders ~12% faster. Classic, not antialiased,
    # mode: antialiased renders are closer to the sample's ground-truth world at 128 px (23.1 / 24.1 dB head / wrist
    # against 22.1 / 23.2, four episodes' first frames; the banana and the button no longer swell), but a grasp
    # policy trained on 300 such demos did worse there, not better (see README, issue 16). Supersampled 4x
    # (``generate --supersample 4``: drawn at 512 px, box-averaged) the first frames of eight episodes are
    # 20.3 / 24.2 dB from the ground truth (classic 19.4 / 22.8, antialiased 19.7 / 22.9, medians) and the
    # banana's yellow covers 1.24x its true area in the head view (classic 1.84x, antialiased 1.63x), for ~3x
    # the generation time on the CPU (3.8 against 11.3 demos/min on 2 workers): opt-in.
    from ..render.splat_world import SplatRenderOptions

    return SplatRenderOptions(sh_degree=1, min_opacity=0.02)


def hybrid_options(objects: str = "gaussians", supersample: int = 1, robot_look: str = "auto") -> HybridOptions:
    """The hybrid renderer's settings with generation's splat settings, objects drawn as ``objects``, the splat layer
    supersampled ``supersample`` x, the robot drawn as ``robot_look`` (what ``generate`` and ``eval-policy``
    expose)."""
    return HybridOptions(splat=replace(_fast_splats(), supersample=int(supersample)), objects=objects,
                         robot_look=robot_look)  # fmt: skip


@dataclass(frozen=True)
class HybridOptions:
    """The hybrid renderer: the Gaussian world posed by physics, the Genesis robot composited over it.

    splat                    per-frame splat render settings
    depth_aware              the robot shows only where it is nearer than the splat surface (False: the paper's
                             mask pasted over everything)
    background               colour (RGB in [0, 1]) where no Gaussian covers a pixel
    robot_render_faces       the robot drawn from a copy with visual meshes decimated to this many faces each
                             (None: the original meshes); render speed on the CPU, physics unchanged
    reuse_hand_camera_robot  cameras on the hand reuse the robot layer while the fingers keep their opening (the
                             hand and fingers do not move in such a camera; only their shading would, slightly)
    objects                  how objects are drawn: "gaussians" (their 3DGS, the method) or "meshes" (Genesis draws
                             their meshes, vertex-coloured from their Gaussians: the paper's mesh-only ablation)
    robot_look               how the robot is drawn: "gaussians" (its own per-link Gaussians as the capture saw it,
                             posed by forward kinematics in the same splat pass as the world: no compositing seam,
                             no Genesis camera), "mesh" (Genesis renders its model's meshes, composited over the
                             splats), "auto" (gaussians when the world has them, ``robot.gaussians``, else mesh)
    """

    splat: SplatRenderOptions = field(default_factory=_fast_splats)
    depth_aware: bool = True
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    robot_render_faces: int | None = 1500
    reuse_hand_camera_robot: bool = True
    objects: str = "gaussians"
    robot_look: str = "auto"

    def robot_gaussians(self, world: Any) -> bool:
        """Whether the robot is drawn from its Gaussians in ``world`` (a WorldConfig)."""
        if self.robot_look not in ("auto", "gaussians", "mesh"):
            raise ValueError(f"robot_look must be auto, gaussians or mesh, got {self.robot_look!r}")
        has = world.robot.gaussians is not None
        if self.robot_look == "gaussians" and not has:
            raise ValueError(
                "robot_look gaussians: the world has no robot Gaussians (robot.gaussians in world.yaml: "
                "train-scene writes them when the capture shows the robot); use robot_look mesh"
            )
        return has and self.robot_look != "mesh"


@dataclass(frozen=True, eq=False)
class EnvConfig:
    """What an environment is; picklable (the world and the task are parsed once, at the border).

    world          the loaded world (the environment copies it before changing anything)
    task           the parsed task (``sim.tasks.parse_task``): its success test is ``terminated``
    renderer       observation renderer: "hybrid" (what generation records) or "ground_truth"
    episode        the frames (size, cameras) and the rate (fps: one step is one control tick)
    horizon        steps after which an episode is truncated (None: never)
    randomization  per-episode jitter, drawn from the episode's seed exactly as generation draws it
    hybrid         the hybrid renderer's settings
    ground_truth   a sample folder holding ``ground_truth.json`` (the ``ground_truth`` renderer's world)
    backend        Genesis backend: "cpu" or "gpu"
    splat_server   a running ``render.splat_server.SplatServer``'s handle: the hybrid splat layer is drawn there
                   (generation's workers sharing one GPU renderer); None: in this process
    """

    world: WorldConfig
    task: Task
    renderer: str = "hybrid"
    episode: EpisodeSpec = field(default_factory=EpisodeSpec)
    horizon: int | None = 200
    randomization: Randomization = field(default_factory=Randomization)
    hybrid: HybridOptions = field(default_factory=HybridOptions)
    ground_truth: Path | None = None
    backend: str = "cpu"
    splat_server: Any = None

    # the episode's, read where the environment is used (one owner: ``episode``)
    size = property(lambda self: self.episode.size, doc="(width, height) of every camera's frames")
    fps = property(lambda self: self.episode.fps, doc="control and video rate (Hz)")
    cameras = property(lambda self: self.episode.cameras, doc="the observed world cameras")


def check_config(cfg: EnvConfig, dt: float = 0.01) -> None:
    """Raise :class:`EnvError` (or the task's ``TaskError``) naming what is wrong with ``cfg`` before anything is
    built; ``dt`` is the twin's physics step."""
    world = cfg.world
    missing = [c for c in cfg.cameras if c not in world.cameras]
    if missing or not cfg.cameras:
        raise EnvError(
            f"the world has no calibrated camera {', '.join(missing) or '(none asked for)'} (cameras: "
            f"{sorted(world.cameras) or 'none'}); calibrate it (`m2m calibrate-handeye`) and compose the world again"
        )
    if cfg.size[0] % 2:
        raise EnvError(f"frames {cfg.size[0]} px wide: the simulator's cameras need an even width (224, 128, 96...)")
    cfg.task.check(world)
    if cfg.renderer == "ground_truth" and (
        cfg.ground_truth is None or not (cfg.ground_truth / "ground_truth.json").is_file()
    ):
        where = f"{cfg.ground_truth} has no ground_truth.json" if cfg.ground_truth is not None else "none was given"
        raise EnvError(
            f"the ground_truth renderer needs a sample's ground truth (a sample folder with ground_truth.json, such "
            f"as samples/tabletop, given as ground_truth=...): {where}. A world reconstructed from your own capture "
            "has no ground truth: use renderer='hybrid'"
        )
    w, h = cfg.size
    if not all(isinstance(v, int) and v >= 2 for v in (w, h)):
        raise EnvError(f"size must be (width, height) in pixels, each >= 2, got {cfg.size!r}")
    per_tick = 1.0 / (cfg.fps * dt) if isinstance(cfg.fps, int) and cfg.fps > 0 else 0.0
    if per_tick < 1 or not math.isclose(per_tick, round(per_tick), abs_tol=1e-6):
        raise EnvError(f"fps must be a positive integer dividing the physics rate ({1 / dt:g} Hz), got {cfg.fps!r}")
    if cfg.hybrid.objects not in ("gaussians", "meshes"):
        raise EnvError(f"hybrid objects must be 'gaussians' or 'meshes', got {cfg.hybrid.objects!r}")
    _check_start_regions(cfg.randomization, world)
    if cfg.horizon is not None and (not isinstance(cfg.horizon, int) or cfg.horizon < 1):
        raise EnvError(f"horizon must be a positive number of steps (or None), got {cfg.horizon!r}")


def _check_start_regions(rand: Randomization, world: WorldConfig) -> None:
    """Each box names a free object, is ordered, and overlaps the world's ``randomize`` region."""
    r = world.randomize
    free = [o.name for o in world.objects] + ([a.name for a in world.articulated] if r.articulated else [])
    if rand.start_regions and not rand.objects:
        raise EnvError("start regions need random object start poses (randomization objects=True)")
    for name, boxes in rand.regions().items():
        if name not in free:
            raise EnvError(f"start region for {name!r}: the world has no object of that name that moves at reset "
                           f"(they are: {', '.join(free) or 'none'})")  # fmt: skip
        for x0, x1, y0, y1 in boxes:
            if not (x0 < x1 and y0 < y1):  # an empty box would only be found out after every redraw
                raise EnvError(f"start region for {name!r}: ({x0}, {x1}, {y0}, {y1}) must be x_min < x_max, "
                               "y_min < y_max")  # fmt: skip
            if x1 < r.x[0] or x0 > r.x[1] or y1 < r.y[0] or y0 > r.y[1]:
                raise EnvError(
                    f"start region for {name!r}: x [{x0}, {x1}], y [{y0}, {y1}] lies outside the world's randomize "
                    f"region x [{r.x[0]}, {r.x[1]}], y [{r.y[0]}, {r.y[1]}] (world.yaml): no start could land in it"
                )
