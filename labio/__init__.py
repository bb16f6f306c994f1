"""Neutral ground of truth and instrument: the one atomic file writer (:mod:`labio.atomic`) and the strict JSON
reader (:mod:`labio.schema`). Imports nothing of the project; ``scenes/``, ``measurement/`` and ``workbench/`` may
all import it.
"""
