"""geomprep: turn object meshes into simulation-ready, geometry-annotated assets.

Stages (one module each): mesh (load/normalize) -> decompose (CoACD) -> mjcf, and from the
normalized mesh: sdf, bbox, superquadric, pointcloud. ``store`` owns the HDF5 layout,
``pipeline`` the caching and scheduling, ``cli`` the ``geomprep`` command.
"""

__version__ = "0.1.0"
