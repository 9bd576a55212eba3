"""Clearpath's Husky in a PyBullet world, as a ROS 2 node publishing the standard topics."""
