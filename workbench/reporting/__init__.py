"""Writing reports: self-contained HTML (:mod:`~workbench.reporting.html_report`) and the iDICs Good Practices
tables (:mod:`~workbench.reporting.idics`, :mod:`~workbench.reporting.experiment_idics`).
"""
