"""The stand over Modbus TCP/RTU: register map (``regmap``), link (``link``, the one pymodbus
client import) and the driver (``stand``: ``ModbusStand``, ``open_stand``)."""

from benchctl.devices.modbus.stand import ModbusStand, open_stand

__all__ = ["ModbusStand", "open_stand"]
