"""Peer DIC tools run side by side with this project's instrument, through the Python engine interface.

Each module is an engine entry point for :mod:`workbench.engines` (``'workbench.peers.<module>:run'``) and
names the reader of its result file (``RESULT_FORMAT``). The peer packages themselves are optional
(``pip install '.[peers]'``) and imported only when an engine runs; reading a result file never needs them.

* :mod:`workbench.peers.pyvale_engine`: pyvale's 2-D DIC (``pyvale.dic.calculate_2d``).
"""
