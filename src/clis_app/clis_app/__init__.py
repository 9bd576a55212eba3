"""clis_app: the application around the learner.

The ``clis`` command and its subcommands, the graph launcher and supervisor, the headless
runner (:mod:`clis_app.core.runner`), experiments (process pool or Ray), figures, reports,
claims, divergence and compare, MCAP bags, the recorder and replay, the Foxglove live view and
doctor. It imports the learning package (:mod:`clis_learner`), the modules
(:mod:`clis_modules`) and the simulator (:mod:`cr_sim`); none of them imports it.
"""
