"""PyBullet twin: ReFlex hand with tactile sites, table, object library, training collection.
Implements the same Hand / Arm interfaces as the real drivers."""
