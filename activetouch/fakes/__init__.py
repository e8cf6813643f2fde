"""In-memory device doubles, no physics: the ``fake`` hand and arm types (`replay`: grasps
replayed from a training dataset) and a joint-level arm in memory (`memory_arm`). Suite-only
mocks live under tests/."""
