"""clis_base: the bottom of the workspace, what every other package stands on.

Nothing here knows a robot, a simulator or a learning rule; every package above imports from it
and it imports none of them (test/test_architecture.py):

- :mod:`~clis_base.params`: parameters declared once as frozen dataclasses with ranges, built
  from the config files (``config/``, installed with this package: :func:`~clis_base.params.
  config_dir`), a bad value named with its key and range;
- :mod:`~clis_base.instants`: the tick grid, the one test of "is ``t`` an instant
  ``t_0 + l tau``" that every scheduler uses (the simulator's lockstep, the modules, the
  arbiter, the learner, the headless runner);
- :mod:`~clis_base.agent_stream`: the agent's random stream, one generator in the headless
  runner's call order, replayed by each agent process (the modules, the arbiter, the learner,
  the runner; not the simulator);
- :mod:`~clis_base.ufunc_loops`: numpy's own ``exp`` and pairwise sum as compiled kernels call
  them (pinned to the numpy versions it was checked on);
- :mod:`~clis_base.trace`: ``CLIS_TRACE`` timestamps along the sensor-to-command path;
- :mod:`clis_base.ros`: the ROS 2 node plumbing (executor, rclpy's private members in one place,
  process setup, parameters declared from the config files, the graph node's base class).
  Pure cores import none of it.
"""
