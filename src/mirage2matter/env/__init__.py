"""The Gymnasium environment of a world's twin, ``mirage2matter/Twin-v0`` (:class:`TwinEnv`), and what it
shares with demonstration generation: the per-episode randomisation (:func:`draw_episode`), the observation
renderers (``hybrid``; ``ground_truth`` on a sample) and the control tick (``Twin.act``). Generation is this
environment with the scripted expert acting: an episode's recorded actions replayed through ``step`` from
``reset(seed=its seed)`` reproduce it.

    import gymnasium, mirage2matter.env
    env = gymnasium.make("mirage2matter/Twin-v0", world="path/to/workspace/world", task="grasp banana", size=224)

Importing this package loads neither gymnasium nor the simulator (the command line and the stages' Configs read
``env.config``): the id is registered when gymnasium is imported, before or after this package, and the episode's
and the environment's names load on first use.
"""

from ..lazy import lazy_names, when_imported
from .config import CAMERAS, EnvConfig, EnvError, HybridOptions, Randomization, check_config

ENV_ID = "mirage2matter/Twin-v0"


def _register() -> None:
    import gymnasium

    if ENV_ID not in gymnasium.registry:
        gymnasium.register(ENV_ID, entry_point="mirage2matter.env.twin_env:TwinEnv")


when_imported("gymnasium", _register)

_LAZY = {"EpisodeDraw": "episode", "draw_episode": "episode", "TwinEnv": "twin_env"}

__getattr__ = lazy_names(__name__, _LAZY)

__all__ = ["CAMERAS", "ENV_ID", "EnvConfig", "EnvError", "HybridOptions", "Randomization", "check_config", *_LAZY]
