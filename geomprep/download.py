"""Resumable, verified HTTP download of one file: retries with backoff, Range resume, MD5 ETag.

The file appears at its destination only once it is whole and matches the server's checksum;
until then the bytes live in ``<dest>.part``, which the next attempt (or run) resumes.
"""

from __future__ import annotations

import os
import re
import time
import urllib.error
import urllib.request
from http.client import HTTPException, HTTPResponse
from pathlib import Path

from tqdm import tqdm

from geomprep import __version__
from geomprep.errors import GeomprepError
from geomprep.hashing import file_md5

# Seconds before the first retry; doubled per attempt and capped. A module constant so tests
# can set it to 0 instead of sleeping.
RETRY_BACKOFF_S = 1.0
RETRY_BACKOFF_MAX_S = 30.0
CHUNK_BYTES = 1 << 20

# An S3 ETag is the object's MD5 (quoted) unless it was a multipart upload ("<md5>-<parts>").
_MD5_ETAG_RE = re.compile(r'^"?([0-9a-fA-F]{32})"?$')
_CONTENT_RANGE_RE = re.compile(r"^bytes (\d+)-(\d+)/(\d+|\*)$")


class _RetryableError(Exception):
    """A download failure worth retrying (network, 5xx, truncation, checksum); message = why."""


class _RestartError(Exception):
    """The server cannot continue our ``.part`` (HTTP 416): start the file from byte 0."""


def _backoff_s(attempt: int) -> float:
    """Seconds to wait before retry number ``attempt`` (0-based): exponential, capped."""
    return min(RETRY_BACKOFF_S * (2**attempt), RETRY_BACKOFF_MAX_S)


def _parse_content_range(value: str | None) -> tuple[int, int | None] | None:
    """(first byte, total size or None) from a ``Content-Range`` header, None if unparsable."""
    match = _CONTENT_RANGE_RE.match((value or "").strip())
    if not match:
        return None
    total = None if match.group(3) == "*" else int(match.group(3))
    return int(match.group(1)), total


def _int_header(value: str | None) -> int | None:
    """A non-negative integer header value, or None if absent or malformed."""
    try:
        number = int((value or "").strip())
    except ValueError:
        return None
    return number if number >= 0 else None


def _open(url: str, have: int, timeout_s: float) -> HTTPResponse:
    """Open ``url`` asking for bytes from ``have`` on; classify failures as retryable or not."""
    headers = {"User-Agent": f"geomprep/{__version__}"}
    if have:
        headers["Range"] = f"bytes={have}-"
    request = urllib.request.Request(url, headers=headers)
    try:
        return urllib.request.urlopen(request, timeout=timeout_s)
    except urllib.error.HTTPError as exc:
        exc.close()
        status = f"HTTP {exc.code} {exc.reason}"
        if exc.code >= 500 or exc.code in (408, 429):
            raise _RetryableError(status) from None
        if exc.code == 416 and have:
            raise _RestartError(status) from None
        raise GeomprepError(
            f"download of {url} failed: {status}: "
            "check the object name and the server address (--url)"
        ) from None
    except (urllib.error.URLError, HTTPException, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise _RetryableError(f"connection error: {reason}") from None


def _byte_bar(total: int | None, initial: int, desc: str, enabled: bool) -> tqdm:
    """A tqdm progress bar counting bytes (on stderr); a no-op when not ``enabled``."""
    return tqdm(
        total=total,
        initial=initial,
        unit="B",
        unit_scale=True,
        unit_divisor=1024,
        desc=desc,
        disable=not enabled,
        leave=False,
    )


def _download_once(url: str, part: Path, *, timeout_s: float, progress: bool, desc: str) -> str:
    """One attempt to complete ``part`` (resuming it if it exists); returns the ETag ('' if none).

    Raises _RetryableError if the body is cut short, the server fails or the size is wrong.
    """
    have = part.stat().st_size if part.exists() else 0
    try:
        response = _open(url, have, timeout_s)
    except _RestartError:
        # 416: our .part is not a prefix the server can continue (e.g. it is longer): restart.
        part.unlink(missing_ok=True)
        have = 0
        response = _open(url, have, timeout_s)
    with response:
        if response.status == 206:
            content_range = _parse_content_range(response.headers.get("Content-Range"))
            if content_range is None or content_range[0] != have:
                part.unlink(missing_ok=True)
                raise _RetryableError("HTTP 206 with an unusable Content-Range; restarting")
            total = content_range[1]
            mode = "ab"
        elif response.status == 200:
            # The server ignored the Range (or we sent none): the body is the whole file.
            have = 0
            total = _int_header(response.headers.get("Content-Length"))
            mode = "wb"
        else:
            raise _RetryableError(f"unexpected HTTP {response.status} {response.reason}")
        status = f"HTTP {response.status}"
        etag = response.headers.get("ETag") or ""
        with open(part, mode) as out, _byte_bar(total, have, desc, progress) as bar:
            while True:
                try:
                    chunk = response.read(CHUNK_BYTES)
                except (HTTPException, OSError) as exc:  # IncompleteRead, reset, timeout
                    raise _RetryableError(
                        f"{status}, body cut off after {have} bytes ({type(exc).__name__})"
                    ) from None
                if not chunk:
                    break
                out.write(chunk)
                have += len(chunk)
                bar.update(len(chunk))
    if total is not None and have < total:
        # Kept on disk: the next attempt resumes from here with a Range request.
        raise _RetryableError(f"{status}, body cut off: got {have} of {total} bytes")
    if total is not None and have > total:
        part.unlink(missing_ok=True)
        raise _RetryableError(f"{status}, got {have} bytes but the file has {total}")
    return etag


def download_file(
    url: str, dest: Path, *, retries: int, timeout_s: float, progress: bool, desc: str
) -> None:
    """Download ``url`` to ``dest`` via ``dest.part``, verified (size, MD5 ETag), with retries.

    ``dest`` appears only once the whole file is there and matches the server's checksum; an
    unverified ``.part`` stays behind for the next run to resume.
    """
    part = dest.with_name(dest.name + ".part")
    dest.parent.mkdir(parents=True, exist_ok=True)
    last_error = ""
    for attempt in range(retries + 1):
        if attempt:
            time.sleep(_backoff_s(attempt - 1))
        try:
            etag = _download_once(url, part, timeout_s=timeout_s, progress=progress, desc=desc)
            match = _MD5_ETAG_RE.match(etag.strip())
            if match and file_md5(part) != match.group(1).lower():
                part.unlink(missing_ok=True)  # a corrupt prefix must not be resumed
                raise _RetryableError(f"MD5 of the download does not match the ETag {etag}")
        except _RetryableError as exc:
            last_error = str(exc)
            continue
        except OSError as exc:  # local disk trouble: retrying will not help
            raise GeomprepError(
                f"cannot write {part}: {exc}: check free disk space and permissions"
            ) from None
        os.replace(part, dest)
        return
    raise GeomprepError(
        f"download of {url} failed after {retries + 1} attempts ({last_error}): "
        "check the network connection and rerun (a partial download resumes)"
    )
