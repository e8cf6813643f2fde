"""The generated hard library: look-alikes differ where they should, builds are repeatable."""

from __future__ import annotations

import numpy as np
import pytest

from activetouch.errors import ActiveTouchError
from activetouch.objects.hard import HARD_OBJECTS, family
from activetouch.objects.library import BUILTIN_OBJECTS, ObjectLibrary, generated_set


def test_the_set_is_large_and_apart_from_the_paper_sets() -> None:
    assert generated_set("hard") == HARD_OBJECTS and len(HARD_OBJECTS) >= 30
    assert not set(HARD_OBJECTS) & set(BUILTIN_OBJECTS)
    assert {family(n) for n in HARD_OBJECTS} >= {"mug", "bottle", "box", "cylinder"}


def test_look_alikes_differ_in_one_feature(tmp_path) -> None:
    names = ["h_box_8x8x8", "h_box_9x8x8", "h_mug_plain", "h_mug_handle_mid"]
    lib = ObjectLibrary(tmp_path)
    assert sorted(lib.ensure_builtins(names)) == sorted(names)
    ext = {n: lib.get(n).extents for n in names}
    np.testing.assert_allclose(ext["h_box_9x8x8"] - ext["h_box_8x8x8"], [0.01, 0, 0], atol=1e-9)
    # The handle adds width along x only; the bodies are the same.
    d = ext["h_mug_handle_mid"] - ext["h_mug_plain"]
    assert d[0] > 0.02 and abs(d[1]) < 1e-6 and abs(d[2]) < 1e-6
    spec = lib.get("h_mug_handle_mid")
    assert spec.set == "hard" and spec.meta["family"] == "mug"
    # Byte-for-byte repeatable, and protected like the builtins.
    sha = spec.meta["sha256"]
    other = ObjectLibrary(tmp_path / "again")
    other.ensure_builtins(["h_mug_handle_mid"])
    assert other.get("h_mug_handle_mid").meta["sha256"] == sha
    assert lib.ensure_builtins(names) == []  # current: nothing rebuilt
    with pytest.raises(ActiveTouchError, match="builtin"):
        lib.remove("h_box_8x8x8")
