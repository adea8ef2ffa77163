"""Transport: the Zenoh bus, rmw_zenoh framing, ROS 2 messages and the session's security."""
