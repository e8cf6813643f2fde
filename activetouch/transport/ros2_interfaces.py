"""The definitions of the ROS 2 interface package ``activetouch_interfaces``, as the daemon's
ROS 2 face registers them (docs/api.md, "ROS 2").

The package itself is ``ros2/activetouch_interfaces/`` in the repository (``.msg`` / ``.srv``
files, ``package.xml``, ``CMakeLists.txt``): a ROS user builds it with colcon. These texts are
copies of those files, so an installed activetouch needs no source tree; a test checks that they
are identical and computes the RIHS01 hashes from the files.
"""

from __future__ import annotations

PACKAGE = "activetouch_interfaces"

PROGRESS_MSG = """\
# After every grasp of a recognition (the daemon's Zenoh `progress`, docs/api.md).
# header.frame_id is the object frame; header.stamp the daemon's wall clock.
std_msgs/Header header
string session_id
uint32 move                  # grasps so far: 1 is the initial grasp
bool has_pose                # false: no pose was reached for this grasp
geometry_msgs/Pose pose      # wrist (hand frame) pose of this grasp in the object frame
int64 pose_id                # index among the model's training poses; -1 if none
uint32 n_contacts
string[] top_labels          # the three most probable classes, best first
float64[] top_probabilities  # one per label
uint32 skipped               # planned poses skipped so far (unreachable)
float64 planning_s           # planning time for this move
float64 elapsed_s            # since the session started
float64 motion_s             # robot seconds moving since the session started
"""

RECOGNITIONRESULT_MSG = """\
# The end of one recognition (the daemon's RecognizeResult, docs/api.md), or why it failed.
std_msgs/Header header
bool success
string error                 # when not success: one line
string error_type            # e.g. BusyError, MessageError, RecognitionAbortedError
string session_id
string label
float64 probability
string[] labels              # top label after each grasp ("" before a triangle was felt)
uint32 moves                 # grasps made, the initial one included
uint32 skipped
string policy
int64 seed                   # the seed used; -1 if unknown
string object                # simulation: the placed object; "" on a real robot
string stop_reason           # confident | budget | exhausted | skips | cancelled
int64[] pose_ids
float64 planning_s
float64 elapsed_s
float64 motion_s
float64 motion_planning_s
float64 grasp_s
float64 search_s
float64 total_s
"""

TACTILE_MSG = """\
# The ReFlex hand's 38 tactile sensors (finger f sensor s is f*9 + s; the palm 27..37).
# header.frame_id is the hand frame.
std_msgs/Header header
float64[38] pressures        # above the zero offset, sensor units
bool[38] contact
float64[3] finger_angles     # proximal joint angles, rad
float64 preshape             # rad
"""

RECOGNIZE_SRV = """\
# One recognition, admitted and run exactly as the Zenoh `recognize` request (docs/api.md).
string policy                # tree | greedy | random | mesh; "" the configured planner.policy
uint32 max_moves             # grasp budget; 0 the configured session.max_moves
int64 seed -1                # -1: the daemon draws one (reported in the result)
string object                # simulation: the object to place; "" on a real robot
uint32 horizon               # 0: the configured planner.horizon
uint32 simulations           # 0: the configured planner.simulations
string session_id            # "": the daemon makes one
---
bool success
string message               # the error when not success
RecognitionResult result
"""

# type name -> (definition, its file in ros2/activetouch_interfaces/)
DEFINITIONS: dict[str, tuple[str, str]] = {
    "activetouch_interfaces/msg/Progress": (PROGRESS_MSG, "msg/Progress.msg"),
    "activetouch_interfaces/msg/RecognitionResult": (
        RECOGNITIONRESULT_MSG,
        "msg/RecognitionResult.msg",
    ),
    "activetouch_interfaces/msg/Tactile": (TACTILE_MSG, "msg/Tactile.msg"),
    "activetouch_interfaces/srv/Recognize": (RECOGNIZE_SRV, "srv/Recognize.srv"),
}


def definitions() -> dict[str, str]:
    """type name -> definition text, for `Ros2Types`."""
    return {k: v[0] for k, v in DEFINITIONS.items()}
