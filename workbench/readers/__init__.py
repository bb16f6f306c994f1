"""Readers of other DIC tools' result files, one module per tool (VIC-3D, MatchID, OpenCorr, Ncorr and MultiDIC), and
the strain conventions they are converted from (:mod:`workbench.readers.conventions`).

Every reader returns :class:`workbench.results.ToolResult` in this project's conventions; :func:`workbench.results.
read_result` dispatches to them by ``--format`` (or recognises the layout, ``--format auto``).
"""
