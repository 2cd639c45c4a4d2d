"""The ``maglevid`` command-line tool.

Every module of this package that defines ``COMMAND`` (the subcommand name),
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> dict`` is a
subcommand; :mod:`maglevid.cli.main` discovers them, so adding a command means
adding one file.
"""
