"""Tests for geomprep.ycb_download (and geomprep.download under it): YCB archives fetched from a
real local HTTP server that can truncate, stall, fail and corrupt on demand."""

from __future__ import annotations

import hashlib
import io
import tarfile
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
import trimesh

from geomprep import cli, download, ycb
from geomprep.errors import GeomprepError
from geomprep.rawstore import complete_objects, read_source
from geomprep.ycb_download import fetch_ycb
from tests.conftest import YCB_DIR
from tests.raw_samples import MTL_TEXT, assert_absent, box_obj, png_bytes

KNIFE = "032_knife"
DICE = "062_dice"


# --------------------------------------------------------------------------------------------
# Test data: archives in the official YCB format
# --------------------------------------------------------------------------------------------


def _tgz(entries: list[tuple[tarfile.TarInfo, bytes | None]]) -> bytes:
    """A gzipped tar built from (member, data) pairs."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for info, data in entries:
            tar.addfile(info, io.BytesIO(data) if data is not None else None)
    return buf.getvalue()


def _file(name: str, data: bytes) -> tuple[tarfile.TarInfo, bytes]:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    info.mode = 0o644
    return info, data


def ycb_archive(name: str) -> bytes:
    """``{name}_google_16k.tgz`` as the YCB server lays it out: {name}/google_16k/..."""
    prefix = f"{name}/google_16k/"
    return _tgz(
        [
            _file(prefix + "textured.obj", box_obj().encode()),
            _file(prefix + "textured.mtl", MTL_TEXT.encode()),
            _file(prefix + "texture_map.png", png_bytes()),
        ]
    )


def archive_path(name: str) -> str:
    return f"/{name}_google_16k.tgz"


# --------------------------------------------------------------------------------------------
# Local HTTP server: S3-style ETag, Content-Length, Range, scripted failures
# --------------------------------------------------------------------------------------------


class _Handler(BaseHTTPRequestHandler):
    """Serves ``server.files``; ``server.plans[path]`` lists per-request behaviours to play."""

    server: _Server

    def log_message(self, format: str, *args: object) -> None:
        pass  # keep test output quiet

    def do_GET(self) -> None:
        srv = self.server
        range_header = self.headers.get("Range")
        with srv.lock:
            srv.requests.append((self.path, range_header))
            plan = srv.plans.get(self.path)
            action = plan.pop(0) if plan else "ok"
        if self.path not in srv.files:
            self.send_error(404)
            return
        if action.isdigit():
            self.send_error(int(action))
            return
        body = srv.files[self.path]
        etag = '"' + hashlib.md5(body).hexdigest() + '"'
        start = 0
        if range_header and action != "norange":
            start = int(range_header.removeprefix("bytes=").rstrip("-"))
        if start >= len(body) and start > 0:
            self.send_response(416)
            self.send_header("Content-Range", f"bytes */{len(body)}")
            self.end_headers()
            return
        payload = body[start:]
        if action == "corrupt":
            payload = bytes([payload[0] ^ 0xFF]) + payload[1:]
        self.send_response(206 if start else 200)
        if start:
            self.send_header("Content-Range", f"bytes {start}-{len(body) - 1}/{len(body)}")
        self.send_header("Content-Length", str(len(payload)))
        self.send_header("ETag", etag)
        self.send_header("Content-Type", "application/x-tar")
        self.end_headers()
        if action == "truncate":
            # Announce the full length, send half, hang up (HTTP/1.0: the connection closes).
            self.wfile.write(payload[: len(payload) // 2])
            self.wfile.flush()
            return
        if action == "stall":
            self.wfile.write(payload[:10])
            self.wfile.flush()
            time.sleep(1.0)  # longer than the client's timeout in the test
            return
        self.wfile.write(payload)


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    files: dict[str, bytes]
    plans: dict[str, list[str]]
    requests: list[tuple[str, str | None]]
    lock: threading.Lock

    @property
    def base_url(self) -> str:
        host, port = self.server_address[:2]
        return f"http://{host}:{port}/"


@pytest.fixture
def server() -> Iterator[_Server]:
    """A real HTTP server on 127.0.0.1 (ephemeral port) in a thread, shut down afterwards."""
    srv = _Server(("127.0.0.1", 0), _Handler)
    srv.files, srv.plans, srv.requests, srv.lock = {}, {}, [], threading.Lock()
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05})
    thread.start()
    try:
        yield srv
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(timeout=5)


@pytest.fixture(autouse=True)
def no_backoff(monkeypatch: pytest.MonkeyPatch) -> None:
    """Retries without sleeping, so failure cases stay fast."""
    monkeypatch.setattr(download, "RETRY_BACKOFF_S", 0.0)


def _serve(srv: _Server, name: str, data: bytes | None = None) -> bytes:
    data = ycb_archive(name) if data is None else data
    srv.files[archive_path(name)] = data
    return data


def _fetch(srv: _Server, raw: Path, names: list[str], **kwargs: object) -> list[str]:
    kwargs.setdefault("retries", 2)
    kwargs.setdefault("timeout_s", 5.0)
    return fetch_ycb(raw, names, base_url=srv.base_url, progress=False, **kwargs)


# --------------------------------------------------------------------------------------------
# fetch_ycb
# --------------------------------------------------------------------------------------------


def test_ycb_objects_match_shared_list() -> None:
    assert len(ycb.OBJECTS) == 78
    assert len(set(ycb.OBJECTS)) == 78
    if YCB_DIR.is_dir():
        assert sorted(ycb.OBJECTS) == sorted(p.name for p in YCB_DIR.iterdir() if p.is_dir())


def test_fetch_normal_download(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, KNIFE)
    masses = tmp_path / "masses.csv"
    masses.write_text(f"object,mass_kg\n{KNIFE},0.031\n")

    assert _fetch(server, raw, [KNIFE], masses_csv=masses) == [KNIFE]

    assert complete_objects(raw) == [KNIFE]
    src = read_source(raw, KNIFE)
    mesh = raw / KNIFE / "google_16k" / "textured.obj"
    assert src == {
        "name": KNIFE,
        "mesh": "google_16k/textured.obj",
        "mass_kg": 0.031,
        "density_kg_m3": None,
        "origin": f"ycb-server: {server.base_url}{KNIFE}_google_16k.tgz",
        "mesh_sha256": hashlib.sha256(mesh.read_bytes()).hexdigest(),
    }
    for sibling in ("textured.mtl", "texture_map.png"):
        assert (raw / KNIFE / "google_16k" / sibling).is_file()
    loaded = trimesh.load(mesh, force="mesh")
    assert loaded.volume == pytest.approx(1.0)
    # The verified archive is consumed; no partial files or staging dirs remain.
    assert list((raw / ".downloads").iterdir()) == []
    assert sorted(p.name for p in raw.iterdir()) == [".downloads", KNIFE]

    # Complete objects are skipped: no second request.
    n_requests = len(server.requests)
    assert _fetch(server, raw, [KNIFE]) == [KNIFE]
    assert len(server.requests) == n_requests
    # ...unless forced; density is recorded when no masses file is given.
    assert _fetch(server, raw, [KNIFE], force=True, density_kg_m3=700.0) == [KNIFE]
    assert len(server.requests) == n_requests + 1
    assert read_source(raw, KNIFE)["density_kg_m3"] == 700.0
    assert read_source(raw, KNIFE)["mass_kg"] is None


def test_fetch_truncated_once_resumes_with_range(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    data = _serve(server, KNIFE)
    server.plans[archive_path(KNIFE)] = ["truncate"]

    assert _fetch(server, raw, [KNIFE]) == [KNIFE]

    assert complete_objects(raw) == [KNIFE]
    assert [r for _, r in server.requests] == [None, f"bytes={len(data) // 2}-"]


def test_fetch_always_truncated_fails_cleanly(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, KNIFE)
    server.plans[archive_path(KNIFE)] = ["truncate"] * 10

    with pytest.raises(GeomprepError) as err:
        _fetch(server, raw, [KNIFE], retries=2)

    msg = str(err.value)
    assert f"{server.base_url}{KNIFE}_google_16k.tgz" in msg
    assert "HTTP 20" in msg and "\n" not in msg
    assert len(server.requests) == 3
    assert_absent(raw, KNIFE)
    assert not (raw / ".downloads" / f"{KNIFE}_google_16k.tgz").exists()


def test_fetch_timeout_is_retried(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, KNIFE)
    server.plans[archive_path(KNIFE)] = ["stall"]

    assert _fetch(server, raw, [KNIFE], timeout_s=0.3) == [KNIFE]
    assert len(server.requests) == 2


def test_fetch_server_error_then_ok(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, DICE)
    server.plans[archive_path(DICE)] = ["503"]

    assert _fetch(server, raw, [DICE]) == [DICE]
    assert len(server.requests) == 2
    assert complete_objects(raw) == [DICE]


def test_fetch_server_error_always(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, DICE)
    server.plans[archive_path(DICE)] = ["503"] * 10

    with pytest.raises(GeomprepError, match="HTTP 503") as err:
        _fetch(server, raw, [DICE], retries=1)
    assert f"{DICE}_google_16k.tgz" in str(err.value)
    assert len(server.requests) == 2
    assert_absent(raw, DICE)


def test_fetch_404_is_not_retried(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"

    with pytest.raises(GeomprepError) as err:
        _fetch(server, raw, [DICE])

    msg = str(err.value)
    assert f"{server.base_url}{DICE}_google_16k.tgz" in msg and "HTTP 404" in msg
    assert msg.endswith("check the object name and the server address (--url)")
    assert len(server.requests) == 1
    assert_absent(raw, DICE)


def test_fetch_connection_refused(tmp_path: Path, server: _Server) -> None:
    # A port nobody listens on: take the server's and close it.
    url = server.base_url
    server.shutdown()
    server.server_close()
    with pytest.raises(GeomprepError, match="connection error"):
        fetch_ycb(tmp_path / "raw", [DICE], base_url=url, retries=1, progress=False)


def test_fetch_corrupted_body_rejected(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, KNIFE)
    server.plans[archive_path(KNIFE)] = ["corrupt"] * 10

    with pytest.raises(GeomprepError, match="MD5"):
        _fetch(server, raw, [KNIFE], retries=1)

    assert_absent(raw, KNIFE)
    # A corrupt .part must not be kept for resuming.
    assert list((raw / ".downloads").iterdir()) == []


def test_fetch_corrupted_once_then_ok(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, KNIFE)
    server.plans[archive_path(KNIFE)] = ["corrupt"]

    assert _fetch(server, raw, [KNIFE]) == [KNIFE]
    # The retry starts over instead of resuming the corrupt bytes.
    assert [r for _, r in server.requests] == [None, None]


def test_fetch_resumes_existing_part(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    data = _serve(server, KNIFE)
    part = raw / ".downloads" / f"{KNIFE}_google_16k.tgz.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(data[:100])

    assert _fetch(server, raw, [KNIFE]) == [KNIFE]

    assert server.requests == [(archive_path(KNIFE), "bytes=100-")]
    assert complete_objects(raw) == [KNIFE]
    assert not part.exists()


def test_fetch_restarts_when_range_ignored(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    data = _serve(server, KNIFE)
    part = raw / ".downloads" / f"{KNIFE}_google_16k.tgz.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(b"x" * 100)  # junk that would corrupt the file if appended to
    server.plans[archive_path(KNIFE)] = ["norange"]

    assert _fetch(server, raw, [KNIFE]) == [KNIFE]
    assert len(server.requests) == 1
    assert complete_objects(raw) == [KNIFE]
    assert len(data) > 100


def test_fetch_restarts_when_part_too_long(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    data = _serve(server, KNIFE)
    part = raw / ".downloads" / f"{KNIFE}_google_16k.tgz.part"
    part.parent.mkdir(parents=True)
    part.write_bytes(data + b"extra")  # the server answers 416 to this Range

    assert _fetch(server, raw, [KNIFE]) == [KNIFE]
    assert [r for _, r in server.requests] == [f"bytes={len(data) + 5}-", None]


@pytest.mark.parametrize(
    "member",
    ["../evil", "/tmp/geomprep-evil-abs", "link"],
)
def test_fetch_rejects_malicious_archive(server: _Server, tmp_path: Path, member: str) -> None:
    raw = tmp_path / "raw"
    entries = [_file(f"{KNIFE}/google_16k/textured.obj", box_obj().encode())]
    if member == "link":
        info = tarfile.TarInfo(f"{KNIFE}/google_16k/texture_map.png")
        info.type = tarfile.SYMTYPE
        info.linkname = "/etc/passwd"
        entries.append((info, None))
    else:
        entries.append(_file(member, b"pwned"))
    _serve(server, KNIFE, _tgz(entries))

    with pytest.raises(GeomprepError, match="refusing to extract"):
        _fetch(server, raw, [KNIFE])

    assert_absent(raw, KNIFE)
    assert not (raw / "evil").exists() and not (tmp_path / "evil").exists()
    assert not Path("/tmp/geomprep-evil-abs").exists()
    assert list((raw / ".downloads").iterdir()) == []


def test_fetch_archive_without_mesh(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, KNIFE, _tgz([_file(f"{KNIFE}/google_16k/readme.txt", b"hi")]))

    with pytest.raises(GeomprepError, match=r"textured.obj") as err:
        _fetch(server, raw, [KNIFE])
    assert_absent(raw, KNIFE)
    assert str(err.value).endswith("check the download source (--url)")


def test_error_hints_name_real_fetch_options() -> None:
    """The download errors point at 'geomprep fetch --url' (there is no --base-url)."""
    options = {opt for param in cli.fetch_cmd.params for opt in param.opts}
    assert "--url" in options and "--base-url" not in options


def test_fetch_unknown_name(tmp_path: Path) -> None:
    with pytest.raises(GeomprepError, match="geomprep list --available"):
        fetch_ycb(tmp_path / "raw", ["032_knfe"], progress=False)
    assert not (tmp_path / "raw").exists()


def test_fetch_redoes_incomplete_object(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, KNIFE)
    stale = raw / KNIFE / "google_16k"
    stale.mkdir(parents=True)
    (stale / "textured.obj").write_text("half a mesh")

    assert _fetch(server, raw, [KNIFE]) == [KNIFE]
    mesh = raw / KNIFE / "google_16k" / "textured.obj"
    assert mesh.read_text() != "half a mesh"
    assert read_source(raw, KNIFE)["mesh_sha256"] == hashlib.sha256(mesh.read_bytes()).hexdigest()
