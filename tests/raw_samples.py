"""Small meshes, materials and textures for the raw-store tests (download and import)."""

from __future__ import annotations

import io
from pathlib import Path

import trimesh
from PIL import Image

from geomprep.rawstore import complete_objects

MTL_TEXT = "newmtl material_0\nmap_Kd texture_map.png\n"


def png_bytes() -> bytes:
    """A tiny real PNG texture."""
    buf = io.BytesIO()
    Image.new("RGB", (2, 2), (200, 30, 30)).save(buf, format="PNG")
    return buf.getvalue()


def box_obj() -> str:
    """A unit box as OBJ text that names the YCB-style material file."""
    body = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(file_type="obj")
    return "mtllib textured.mtl\nusemtl material_0\n" + body


def assert_absent(raw: Path, name: str) -> None:
    """No complete object, no object dir, no staging leftovers for ``name``."""
    assert name not in complete_objects(raw)
    assert not (raw / name).exists()
    assert not list(raw.glob(f".{name}.*"))
