"""The ``m2m`` commands that are not pipeline stages (render, bench, board, validate, sample, world edits,
task, demo): each module registers its subcommand(s) with ``register(subparsers)``. The stage commands are
generated from the stages' Configs in ``cli.py``."""
