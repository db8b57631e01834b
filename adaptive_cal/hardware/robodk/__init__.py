"""Motion through the RoboDK API (``adapter``) and its config.

Nothing is imported here, so loading a config does not load the device library."""
