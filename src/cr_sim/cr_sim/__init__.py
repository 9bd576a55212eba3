"""cr_sim: the Cyber Rodent arena simulator (pure core in ``cr_sim.core``, ROS node around it)."""
