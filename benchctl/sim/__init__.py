"""Simulated devices that are real protocol peers (Modbus server, slcan adapter, NMEA talker)."""
