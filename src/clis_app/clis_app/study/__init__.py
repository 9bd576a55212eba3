"""``clis study``: a grid of experiments over layouts, start protocols and presets.

:mod:`~clis_app.study.study` plans the grid, runs what is missing and stores one summary per
run; :mod:`~clis_app.study.report` and :mod:`~clis_app.study.figures` draw the report from the
summaries alone (docs/study.md).
"""
