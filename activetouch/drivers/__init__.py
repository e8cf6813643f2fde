"""Hardware drivers behind the Hand / Arm interfaces: the ReFlex TakkTile (UDP) and SF
(Dynamixel serial) hands, the BarrettHand BH8-282 (CAN, python-can) and the Baxter arm (Zenoh
to its ROS 1 bridge)."""
