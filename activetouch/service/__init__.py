"""The parts a user talks to: CLI, recognition session, daemon and its Zenoh API."""
