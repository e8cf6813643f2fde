"""BarrettHand BH8-280/282 over CAN (python-can): the frame codec (`codec`), the hand's
kinematics and pad cells (`kinematics`) and the `Hand` driver (`bh8`).

Wire facts and their sources: ../shared/protocol-facts.md section C (libbarrett, pyHand).
Modules here import only the standard library and numpy at import time; python-can is
imported when a bus is opened.
"""
