"""The wire: ROS 2 messages in CDR over Zenoh, the key registry, sessions."""
