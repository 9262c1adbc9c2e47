"""Subcommands of the ``ao4d`` command line, one module each (see ``ao4d.cli``)."""
