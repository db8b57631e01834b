"""The operator as motion and probe (``adapter``) and its config.

Nothing is imported here, so loading a config does not load the device library."""
