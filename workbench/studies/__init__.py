"""Studies on Dask: study files (:mod:`~workbench.studies.study`), their cases (:mod:`~workbench.studies.cases`),
the sweep (:mod:`~workbench.studies.sweep`), reports (:mod:`~workbench.studies.report`), error budgets
(:mod:`~workbench.studies.budget`) and the Fig 6 causes study (:mod:`~workbench.studies.fig6_causes`).
"""
