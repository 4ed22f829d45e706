"""Instruments on a CAN bus through python-can: CANopen CiA 410, J1939 PGN 61459, NMEA 2000
PGN 127257. ``bus.open_can_bus`` opens the transport; the drivers get it handed in."""
