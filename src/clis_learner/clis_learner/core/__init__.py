"""Pure core: numpy/scipy only, no rclpy or message types."""
