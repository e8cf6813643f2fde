"""The paper's observation model p(z' | z, a, y), as flat arrays the planner can run on.

Vocabulary (Zhang et al. 2017, Sec. III-IV):
- *pose*: a nominal absolute wrist pose in the object frame; training poses of all classes are
  pooled (the object pose is known at test time, so every class's grid is superimposed).
- *action* a: the relative wrist pose between two poses, discretised with the authors' cells.
- *cell*: the discretised triangle (or, at grasp level, a grasp's representative cell) that an
  observation leaves behind and that the next transition is conditioned on (the paper's z).
- *outcome*: what one simulated observation adds to the histogram: one triangle's bin at
  triangle granularity, every triangle bin of a training grasp at grasp granularity.

Every table is a flat numpy array (CSR where ragged), so the tree search can run compiled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GRANULARITIES = ("triangle", "grasp")


@dataclass(frozen=True)
class ObservationModel:
    granularity: str  # "triangle" | "grasp"
    class_names: tuple[str, ...]
    n_bins: int  # histogram length (bins ** 3)
    n_cells: int  # number of conditioning cells C
    # Poses (P): pooled nominal wrist poses in the object frame.
    pose_xyz: np.ndarray  # (P, 3) float64
    pose_quat: np.ndarray  # (P, 4) float64, x y z w
    # Actions (A): discretised relative poses and their movement cost c_m(a) in [0, 1].
    action_delta: np.ndarray  # (A, 7) float64: translation, quaternion (x y z w)
    action_cost: np.ndarray  # (A,) float64
    # Transitions from each pose (CSR over poses): action taken and pose reached.
    edge_ptr: np.ndarray  # (P + 1,) int64
    edge_action: np.ndarray  # (E,) int64
    edge_target: np.ndarray  # (E,) int64
    # Outcomes (O): the cell each leaves behind and the histogram bins it adds (CSR).
    out_cell: np.ndarray  # (O,) int64
    out_ptr: np.ndarray  # (O + 1,) int64
    out_bin: np.ndarray  # (X,) int64, a bin repeated once per triangle that falls in it
    # Tallies keyed by (class y, action a, cell z): code = (y * A + a) * C + z, sorted ascending.
    tally_key: np.ndarray  # (R,) int64
    tally_ptr: np.ndarray  # (R + 1,) int64
    tally_out: np.ndarray  # (S,) int64 outcome ids
    tally_cum: np.ndarray  # (S,) float64 cumulative probability within each row (row ends at 1)
    # Fallback when the current cell never met action a for class y: p(z' | a, y),
    # keyed by code = y * A + a, sorted ascending.
    marg_key: np.ndarray  # (R2,) int64
    marg_ptr: np.ndarray  # (R2 + 1,) int64
    marg_out: np.ndarray  # (S2,) int64
    marg_cum: np.ndarray  # (S2,) float64

    @property
    def n_classes(self) -> int:
        return len(self.class_names)

    @property
    def n_poses(self) -> int:
        return len(self.pose_xyz)

    @property
    def n_actions(self) -> int:
        return len(self.action_cost)

    @property
    def n_outcomes(self) -> int:
        return len(self.out_cell)
