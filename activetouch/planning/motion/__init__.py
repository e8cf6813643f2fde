"""Arm motion: from a wrist pose in the object frame to joint motion on a joint-level `Arm`.

`WristMotion` is what the recognition session and training collection move with. Each
implementation owns the step from the object frame to the arm's joints: `floating` for the
twin's floating wrist (its joints are the hand pose in the base frame); the Baxter
kinematics, collision checking, paths and ruckig timing live beside it."""
