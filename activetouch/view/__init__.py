"""`activetouch view`: a live 3-D view (Rerun) of the daemon's recognitions, from what the
daemon publishes (scene.py: messages -> Rerun; live.py: the Zenoh feed and the loopback server).
Needs the `view` extra (rerun-sdk)."""
