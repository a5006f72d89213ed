"""The ``atris calib`` subcommands: thin shells over the ``calib`` library functions.

Each module has ``add_arguments(parser)`` and ``run(args) -> int``; the table of
:mod:`atris_node.cli.calib` imports them lazily.
"""
