"""ReFlex hand drivers: TakkTile/Beta over UDP (`takktile`), SF over Dynamixel serial (`sf`),
and byte-level emulators of both (`emulator_takktile`, `emulator_sf`).

Wire facts and their sources: docs/protocols/reflex.md. Modules here import only the standard
library and numpy at import time; sockets, serial ports and dynamixel-sdk are opened in `make`.
"""
