"""Digests of a file's bytes: SHA-256 identifies mesh sources, MD5 checks downloads (S3 ETags)."""

from __future__ import annotations

import hashlib
from pathlib import Path


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    # file_digest reads in blocks, so a large scan or archive is never held in memory at once.
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def file_md5(path: Path) -> str:
    """Hex MD5 of a file's bytes (only to compare with a server's ETag, not for security)."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, lambda: hashlib.md5(usedforsecurity=False)).hexdigest()
