"""Zenoh transport: sessions, key expressions built in one place (keys.py), the message schemas and
their codec (messages.py), and the ROS 2 (rmw_zenoh) face."""
