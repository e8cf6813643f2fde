"""Where activetouch keeps its data: the object library, datasets, models and reports.

`--data DIR` on the CLI wins, then the ACTIVETOUCH_HOME environment variable, then the user
data directory of the platform (e.g. ~/.local/share/activetouch).
"""

from __future__ import annotations

import os
from pathlib import Path

import platformdirs


def data_dir(explicit: str | os.PathLike | None = None) -> Path:
    if explicit:
        root = Path(explicit)
    elif os.environ.get("ACTIVETOUCH_HOME"):
        root = Path(os.environ["ACTIVETOUCH_HOME"])
    else:
        root = Path(platformdirs.user_data_dir("activetouch"))
    return root.expanduser()


DEFAULT_DATASET = "twin"  # datasets/<name>: what `train` collects into by default
DEFAULT_MODEL = "default"  # models/<name>: what `train` writes and `recognize` loads


def objects_dir(root: Path) -> Path:
    return root / "objects"


def datasets_dir(root: Path) -> Path:
    return root / "datasets"


def models_dir(root: Path) -> Path:
    return root / "models"


def default_dataset(root: Path, variant: str = "") -> Path:
    """`variant`: what makes the grasps differ from the floating twin's (an arm that reaches
    fewer poses, another sensing), so each collects into its own dataset."""
    return datasets_dir(root) / (f"{DEFAULT_DATASET}-{variant}" if variant else DEFAULT_DATASET)


def default_model(root: Path, hand_family: str = "reflex") -> Path:
    """The model `train` writes and `recognize` loads: ``models/default`` for the ReFlex,
    ``models/default-<family>`` for another hand (a BH8 model cannot classify ReFlex grasps)."""
    name = DEFAULT_MODEL if hand_family == "reflex" else f"{DEFAULT_MODEL}-{hand_family}"
    return models_dir(root) / name


def recordings_dir(root: Path) -> Path:
    """Every recognition's MCAP file (docs/recordings.md)."""
    return root / "recordings"
