"""NMEA 2000 PGN 127257 Attitude, from ``drivers/nmea2000_attitude.dbc``.

One 8-byte frame: SID, yaw, pitch, roll (int16, 1e-4 rad), reserved. Raw 0x7FFF (not
available), 0x7FFE (out of range) and anything beyond ±π rad are counted as ``range`` and the
frame skipped (only for the axes the config asks for). The SID is the sample's ``counter``
(255 = not available → None). No device time. Identity: the source address of the first frame.
"""

from __future__ import annotations

import math

from benchctl.devices.can.dbc import DbcAngleInstrument, DbcAngleSpec

#: |raw| above this is beyond ±π rad at 1e-4 rad/bit (0x7FFD…0x7FFF are the special codes)
N2K_MAX_ANGLE_RAW = 31416

SPEC = DbcAngleSpec(
    protocol="NMEA 2000",
    message="Attitude",
    angle_signals={"pitch": "Pitch", "roll": "Roll"},
    to_deg=180.0 / math.pi,
    raw_valid=lambda r: -N2K_MAX_ANGLE_RAW <= r <= N2K_MAX_ANGLE_RAW,
    counter_signal="SID",
    counter_not_available=255,
)


class Nmea2000Attitude(DbcAngleInstrument):
    """An NMEA 2000 attitude sensor broadcasting PGN 127257; implements ``AngleSensor``."""

    spec = SPEC
