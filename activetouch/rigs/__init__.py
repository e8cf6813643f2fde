"""A real driver on its byte-level emulator, backed by the twin's physics (`emulate = "twin"`), and
the `emulate` runner: how the drivers are exercised end to end without hardware."""
