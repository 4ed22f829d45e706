"""The stand over Modbus TCP/RTU: register map (``regmap``, read and validated by
``regmap_load``), link (``link``, the one pymodbus client import) and the driver (``stand``:
``ModbusStand``, ``open_stand``), built on its register side (``stand_io``) and its setpoint
history (``setpoints``), with the table limit check (``table_limits``)."""

from benchctl.devices.modbus.stand import ModbusStand, open_stand

__all__ = ["ModbusStand", "open_stand"]
