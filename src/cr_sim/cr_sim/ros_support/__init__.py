"""Generic ROS 2 plumbing every package of the project uses (no robot and no CLIS in it).

- :mod:`~cr_sim.ros_support.executor`: the lean single-threaded executor and ``make_executor``;
- :mod:`~cr_sim.ros_support.rclpy_private`: the one place that touches rclpy's private members,
  for the rclpy version it was written for;
- :mod:`~cr_sim.ros_support.lifecycle`: a node process's heap, real-time priority, clean stop;
- :mod:`~cr_sim.ros_support.ros_params`: parameters declared from the config files;
- :mod:`~cr_sim.ros_support.trace`, :mod:`~cr_sim.ros_support.profiling`: development aids
  (``CLIS_TRACE``, ``CLIS_PROFILE``).
"""
