"""Tactile zero offsets and thresholds, finger zeroing, hand-mount and object frames."""
