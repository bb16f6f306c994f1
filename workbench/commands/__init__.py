"""The ``workbench`` command line, one module per verb: each has ``add_parser(sub)`` and ``HANDLERS`` (its
(command, subcommand) -> handler), assembled by :mod:`workbench.cli`; :mod:`~workbench.commands.options` checks
every option and file before the first long computation.
"""
