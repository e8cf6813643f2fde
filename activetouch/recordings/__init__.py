"""Every recognition recorded as MCAP (issue 25; docs/recordings.md).

`format` names the channels and builds their messages (standard ROS 2 types, CDR through
rosbags' typestore, where one exists; JSON-schema channels for the rest), `writer` writes a
recording incrementally (flushed after every grasp), `reader` reads one back (also a file cut
short by a crash, without its summary and footer), `store` finds, lists and prunes the files
under ``<data>/recordings/``.
"""
