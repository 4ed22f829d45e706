"""Device drivers: a stand over Modbus, instruments over CAN or serial. See ``base`` for the
capability interfaces the run layer depends on."""
