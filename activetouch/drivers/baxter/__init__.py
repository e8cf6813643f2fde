"""Baxter over zenoh-bridge-ros1: ROS 1 keys and bytes (`ros1`), the `Arm` driver (`arm`) and a
byte-level emulator (`emulator`). docs/protocols/baxter.md has the facts and their sources."""
