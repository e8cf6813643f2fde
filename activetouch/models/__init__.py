"""Robot models: the ReFlex and the BarrettHand (geometry, forward kinematics, tactile sensor
sites) and their URDF."""
