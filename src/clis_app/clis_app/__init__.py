"""clis_app: the application around the learner, in rooms by job.

:mod:`clis_app.cli` (the ``clis`` command), :mod:`clis_app.graph` (running the node graph:
``clis run``), :mod:`clis_app.experiments` (the headless runner and ``clis experiment``, its
figures, reports, claims and comparisons), :mod:`clis_app.study` (``clis study``),
:mod:`clis_app.bags` (MCAP bags: record, replay, offline learning) and :mod:`clis_app.live`
(the Foxglove live view); :mod:`clis_app.files` writes every output file atomically. It imports
the learning package (:mod:`clis_learner`), the modules (:mod:`clis_modules`) and the simulator
(:mod:`cr_sim`); none of them imports it.
"""
