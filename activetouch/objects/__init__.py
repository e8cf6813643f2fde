"""The object library: its registry and mesh import (library.py), shape building (shapes.py), the
paper's objects (paper.py) and the generated hard set (hard.py)."""
