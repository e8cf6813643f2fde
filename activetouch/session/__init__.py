"""One recognition: the grasp-plan-update loop on any Hand and WristMotion (loop.py), which
contacts and sensors count, a recognition in the twin or on the configured devices (local.py),
and the replay of a recording."""
