"""cr_bridge: the robot interface for the real Cyber Rodent."""
