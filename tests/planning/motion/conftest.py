import pytest


@pytest.fixture(scope="session")
def baxter():
    """The left arm model (loading meshes takes ~2 s: once per session)."""
    pytest.importorskip("pinocchio")
    from activetouch.planning.motion.robot import load_arm

    return load_arm()
