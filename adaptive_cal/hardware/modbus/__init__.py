"""Modbus PLC/HMI: the register map (``registers``), link, motion and probe (``adapter``), its config.

Nothing is imported here, so loading a config does not load the device library."""
