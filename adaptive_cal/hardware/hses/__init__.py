"""Yaskawa HSES: the UDP protocol (``protocol``), the motion adapter (``adapter``), its config.

Nothing is imported here, so loading a config does not load the device library."""
