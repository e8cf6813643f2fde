"""Hardware drivers behind the Hand / Arm interfaces (ReFlex over UDP or serial, Baxter bridge)."""
