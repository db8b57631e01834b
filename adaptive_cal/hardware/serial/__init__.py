"""Serial gauges (the ``serial`` probe adapter): presets and parser, the probe (``adapter``), its config.

Nothing is imported here, so loading a config does not load the device library."""
