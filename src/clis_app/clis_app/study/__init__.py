"""``clis study``: a grid of experiments over layouts, start protocols and presets.

:mod:`~clis_app.study.plan` reads a SPEC into runs and checks it; :mod:`~clis_app.study.study`
is the command: it runs what is missing and stores one summary per run;
:mod:`~clis_app.study.report` computes the report from the summaries alone,
:mod:`~clis_app.study.markdown` writes its text and :mod:`~clis_app.study.figures` its figures
(docs/study.md).
"""
