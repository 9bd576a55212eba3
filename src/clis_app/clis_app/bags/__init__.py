"""Recording and replaying runs as rosbag2 MCAP bags: ``clis record``, ``clis replay``,
``clis learn``, ``clis bag``.

:mod:`~clis_app.bags.mcap` reads and writes the bags (ROS-free, the raw CDR bytes);
:mod:`~clis_app.bags.recorder_node` is the recorder node (``ros2 run clis_app recorder``);
:mod:`~clis_app.bags.replay` plays a bag back on a graph; :mod:`~clis_app.bags.commands` is the
command line, including offline learning from bags (docs/bags.md).
"""
