"""Other DIC tools on the workbench's datasets: open a dataset and its truth (:mod:`~workbench.scoring.datasets`),
export it as a tool reads it (:mod:`~workbench.scoring.export`), score results (:mod:`~workbench.scoring.metrics`),
the accuracy gate (:mod:`~workbench.scoring.gate`).
"""
