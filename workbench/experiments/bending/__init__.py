"""The paper's three-point bending test (Figs 7-8): ``scenes`` (the FE-deformed beam and its truth), ``run``
(render, measure, score), ``report`` (figures and tables).
"""
