"""Running the CLIS node graph: ``clis run``.

:mod:`~clis_app.graph.run` is the command (its options, checked before anything starts);
:mod:`~clis_app.graph.plan` lays out the graph's processes and their parameters;
:mod:`~clis_app.graph.supervise` starts them as ``ros2 run`` would and restarts a child that
dies, or :mod:`~clis_app.graph.single` runs every node in one process;
:mod:`~clis_app.graph.progress` follows the learner's progress in one line;
:mod:`~clis_app.graph.curve` writes the run's curve and summary;
:mod:`~clis_app.graph.ros_env` keeps DDS on the loopback and picks the domain id for every
process the project starts.
"""
