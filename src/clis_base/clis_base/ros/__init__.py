"""The ROS 2 node plumbing every node of the project uses (no robot and no learning rule in it).

- :mod:`~clis_base.ros.executor`: the lean single-threaded executor and ``make_executor``;
- :mod:`~clis_base.ros.rclpy_private`: the one place that touches rclpy's private members,
  for the rclpy version it was written for;
- :mod:`~clis_base.ros.process`: a node process's setup and end: its heap, real-time
  priority, a clean stop when a shutdown races the executor;
- :mod:`~clis_base.ros.ros_params`: parameters declared from the config files, ``--help``;
- :mod:`~clis_base.ros.qos`: the depth of the graph's streams and the proposals' liveliness;
- :mod:`~clis_base.ros.graph_node`: :class:`~clis_base.ros.graph_node.GraphNode`, the base of
  the CLIS graph's nodes (parameters, sim time, wakeups on demand, ``main``);
- :mod:`~clis_base.ros.profiling`: ``CLIS_PROFILE``, a development aid.

Pure cores (the ``core`` subpackages) import none of it.
"""
