"""The workbench: experiments, studies, scoring and the command line over the truth side (``scenes``) and the
instrument (``measurement``).

Rooms, lowest first (a module imports only from its room or a lower one; ``tests/test_architecture.py``):
the core modules here (config, scenario, store, manifest, rigs, poses, engines, results, peers), ``reporting``,
``experiments`` (one package per experiment), ``studies``, ``scoring``, ``commands`` (one module per CLI verb),
and ``cli``. See ``docs/architecture.rst``.
"""
