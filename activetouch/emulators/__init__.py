"""Byte-level emulators of the real devices (ReFlex TakkTile over UDP, ReFlex SF over serial,
BarrettHand over CAN, the Baxter bridge), written from the protocol facts; they import no driver
code."""
