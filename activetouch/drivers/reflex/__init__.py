"""ReFlex hand drivers: TakkTile/Beta over UDP (`takktile`, with its packets in `codec` and its
stored calibration in `takktile_calibration`), SF over Dynamixel serial (`sf`). Their byte-level
emulators are in `activetouch.emulators` and import nothing from here.

Wire facts and their sources: docs/protocols/reflex.md. Modules here import only the standard
library and numpy at import time; sockets, serial ports and dynamixel-sdk are opened in `make`.
"""
