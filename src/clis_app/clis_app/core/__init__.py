"""The application's pure cores (no rclpy): the headless runner and the MCAP bag writer."""
