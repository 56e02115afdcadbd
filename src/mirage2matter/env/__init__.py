"""The Gymnasium environment of a world's twin, ``mirage2matter/Twin-v0`` (:class:`TwinEnv`), and what it
shares with demonstration generation: the per-episode randomisation (:func:`draw_episode`), the observation
renderers (``hybrid``; ``ground_truth`` on a sample) and the control tick (``Twin.act``). Generation is this
environment with the scripted expert acting: an episode's recorded actions replayed through ``step`` from
``reset(seed=its seed)`` reproduce it.

    import gymnasium, mirage2matter.env
    env = gymnasium.make("mirage2matter/Twin-v0", world="path/to/workspace/world", task="grasp banana", size=224)
"""

import gymnasium

from .config import CAMERAS, EnvConfig, EnvError, HybridOptions, Randomization, check_config
from .episode import EpisodeDraw, draw_episode

ENV_ID = "mirage2matter/Twin-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(ENV_ID, entry_point="mirage2matter.env.twin_env:TwinEnv")

__all__ = [
    "CAMERAS",
    "ENV_ID",
    "EnvConfig",
    "EnvError",
    "EpisodeDraw",
    "HybridOptions",
    "Randomization",
    "TwinEnv",
    "check_config",
    "draw_episode",
]


def __getattr__(name: str):
    # TwinEnv imports the simulator's stack (torch); importing this package (datagen.config does) stays light.
    if name == "TwinEnv":
        from .twin_env import TwinEnv

        return TwinEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
