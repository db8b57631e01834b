"""Hardware: what moves the probe and what reads it, one folder per device family.

``base`` holds the shared part -- the ``Motion`` and ``ProbeDevice`` protocols, ``Sample`` and
``Touch``, the errors, and the ``ProbeCycle`` that owns the touch sequence; ``config`` the base of
every config block. Each family (``hses``, ``modbus``, ``serial``, ``manual``, ``robodk``) has its
``config`` (the cell-file block, validated) beside its ``adapter``. This layer imports nothing
above it: the cell file composes the configs, ``run.devices`` builds the adapters.
"""
