"""Hardware adapters: protocols, the probe cycle, and one module per device family."""
