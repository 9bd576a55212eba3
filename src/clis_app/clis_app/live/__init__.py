"""The live view: ``ros2 run clis_app foxglove`` (``clis run --foxglove``), the graph's
topics served to the Foxglove app through Foxglove's own WebSocket server, with its layout
(docs/foxglove.md).
"""
