"""geomgrasp: what the asset pipeline (``geomprep``) and the trainer (``trainer``) both use.

Neither package imports the other's internals for these: ``rotations`` (the one rotation module,
torch), ``files`` (atomic writes), ``config_schema`` (checked config dataclasses from TOML),
``cli`` (one-line errors on the command line), ``machine`` (the machine in words) and
``errors`` (the base of both packages' user errors). The trainer reaches geomprep's output only
through ``geomprep.contract``.
"""
