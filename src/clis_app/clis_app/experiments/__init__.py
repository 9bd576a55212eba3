"""Experiments without ROS: ``clis experiment``, ``clis report``, ``clis compare``.

:mod:`~clis_app.experiments.runner` is the headless runner (the same cores as the node graph,
driven by a discrete-event loop; ROS-free); :mod:`~clis_app.experiments.experiment` runs its
jobs over seeds and conditions on a process pool or on Ray
(:mod:`~clis_app.experiments.ray_backend`) and merges them;
:mod:`~clis_app.experiments.figures`, :mod:`~clis_app.experiments.report`,
:mod:`~clis_app.experiments.claims`, :mod:`~clis_app.experiments.divergence` and
:mod:`~clis_app.experiments.compare` draw and judge what the runs saved.
"""
