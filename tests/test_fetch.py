"""Tests for geomprep.fetch: YCB download against a real local HTTP server, and local import."""

from __future__ import annotations

import hashlib
import io
import json
import tarfile
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
import trimesh
from PIL import Image

from geomprep import fetch
from geomprep.errors import GeomprepError
from geomprep.fetch import (
    complete_objects,
    fetch_ycb,
    import_directory,
    read_masses,
    read_source,
)
from tests.conftest import YCB_DIR

KNIFE = "032_knife"
DICE = "062_dice"


# --------------------------------------------------------------------------------------------
# Test data: meshes and archives in the official YCB format
# --------------------------------------------------------------------------------------------


def _png_bytes() -> bytes:
    """A tiny real PNG texture."""
    buf = io.BytesIO()
    Image.new("RGB", (2, 2), (200, 30, 30)).save(buf, format="PNG")
    return buf.getvalue()


def _box_obj() -> str:
    """A unit box as OBJ text that names the YCB-style material file."""
    body = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(file_type="obj")
    return "mtllib textured.mtl\nusemtl material_0\n" + body


MTL_TEXT = "newmtl material_0\nmap_Kd texture_map.png\n"


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
            _file(prefix + "textured.obj", _box_obj().encode()),
            _file(prefix + "textured.mtl", MTL_TEXT.encode()),
            _file(prefix + "texture_map.png", _png_bytes()),
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
    monkeypatch.setattr(fetch, "RETRY_BACKOFF_S", 0.0)


def _serve(srv: _Server, name: str, data: bytes | None = None) -> bytes:
    data = ycb_archive(name) if data is None else data
    srv.files[archive_path(name)] = data
    return data


def _fetch(srv: _Server, raw: Path, names: list[str], **kwargs: object) -> list[str]:
    kwargs.setdefault("retries", 2)
    kwargs.setdefault("timeout_s", 5.0)
    return fetch_ycb(raw, names, base_url=srv.base_url, progress=False, **kwargs)


def _assert_absent(raw: Path, name: str) -> None:
    """No complete object, no object dir, no staging leftovers for ``name``."""
    assert name not in complete_objects(raw)
    assert not (raw / name).exists()
    assert not list(raw.glob(f".{name}.*"))


# --------------------------------------------------------------------------------------------
# fetch_ycb
# --------------------------------------------------------------------------------------------


def test_ycb_objects_match_shared_list() -> None:
    assert len(fetch.YCB_OBJECTS) == 78
    assert len(set(fetch.YCB_OBJECTS)) == 78
    if YCB_DIR.is_dir():
        assert sorted(fetch.YCB_OBJECTS) == sorted(p.name for p in YCB_DIR.iterdir() if p.is_dir())


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
    _assert_absent(raw, KNIFE)
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
    _assert_absent(raw, DICE)


def test_fetch_404_is_not_retried(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"

    with pytest.raises(GeomprepError) as err:
        _fetch(server, raw, [DICE])

    msg = str(err.value)
    assert f"{server.base_url}{DICE}_google_16k.tgz" in msg and "HTTP 404" in msg
    assert len(server.requests) == 1
    _assert_absent(raw, DICE)


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

    _assert_absent(raw, KNIFE)
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
    entries = [_file(f"{KNIFE}/google_16k/textured.obj", _box_obj().encode())]
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

    _assert_absent(raw, KNIFE)
    assert not (raw / "evil").exists() and not (tmp_path / "evil").exists()
    assert not Path("/tmp/geomprep-evil-abs").exists()
    assert list((raw / ".downloads").iterdir()) == []


def test_fetch_archive_without_mesh(server: _Server, tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    _serve(server, KNIFE, _tgz([_file(f"{KNIFE}/google_16k/readme.txt", b"hi")]))

    with pytest.raises(GeomprepError, match=r"textured.obj"):
        _fetch(server, raw, [KNIFE])
    _assert_absent(raw, KNIFE)


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


# --------------------------------------------------------------------------------------------
# read_masses, complete_objects, read_source
# --------------------------------------------------------------------------------------------


def test_read_masses(tmp_path: Path) -> None:
    path = tmp_path / "m.csv"
    path.write_text("object,mass_kg\na,0.5\n\nb_2,1e-3\n")
    assert read_masses(path) == {"a": 0.5, "b_2": 0.001}


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("", "header"),
        ("name,mass\na,1\n", "header"),
        ("object,mass_kg\na\n", r":2: expected 2 columns"),
        ("object,mass_kg\na,1\nb,heavy\n", r":3: mass of 'b'"),
        ("object,mass_kg\na,-1\n", "positive"),
        ("object,mass_kg\na,0\n", "positive"),
        ("object,mass_kg\na,nan\n", "positive"),
        ("object,mass_kg\na,1\na,2\n", "twice"),
        ("object,mass_kg\n../x,1\n", "invalid object name"),
    ],
)
def test_read_masses_malformed(tmp_path: Path, text: str, pattern: str) -> None:
    path = tmp_path / "m.csv"
    path.write_text(text)
    with pytest.raises(GeomprepError, match=pattern) as err:
        read_masses(path)
    assert "\n" not in str(err.value)


def test_read_masses_missing_file(tmp_path: Path) -> None:
    with pytest.raises(GeomprepError, match="cannot read masses file"):
        read_masses(tmp_path / "nope.csv")


def test_complete_objects_and_read_source_missing(tmp_path: Path) -> None:
    assert complete_objects(tmp_path / "absent") == []
    (tmp_path / "half").mkdir()
    assert complete_objects(tmp_path) == []
    with pytest.raises(GeomprepError, match="not in"):
        read_source(tmp_path, "half")
    with pytest.raises(GeomprepError, match="invalid object name"):
        read_source(tmp_path, "../etc")


# --------------------------------------------------------------------------------------------
# import_directory
# --------------------------------------------------------------------------------------------

needs_ycb = pytest.mark.skipif(not YCB_DIR.is_dir(), reason=f"no YCB copy at {YCB_DIR}")


@needs_ycb
def test_import_ycb_dir_with_masses(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    assert import_directory(YCB_DIR, raw, [DICE, KNIFE]) == [KNIFE, DICE]

    assert complete_objects(raw) == [KNIFE, DICE]
    masses = read_masses(YCB_DIR / "masses.csv")
    for name in (KNIFE, DICE):
        src = read_source(raw, name)
        assert src["mesh"] == "google_16k/textured.obj"
        assert src["mass_kg"] == masses[name] and src["density_kg_m3"] is None
        assert src["origin"] == f"dir: {YCB_DIR.resolve()}"
        copied = raw / name / "google_16k"
        assert sorted(p.name for p in copied.iterdir()) == sorted(
            p.name for p in (YCB_DIR / name / "google_16k").iterdir()
        )
        assert (
            src["mesh_sha256"] == hashlib.sha256((copied / "textured.obj").read_bytes()).hexdigest()
        )
    assert read_source(raw, KNIFE)["mass_kg"] == 0.031
    mesh = trimesh.load(raw / DICE / "google_16k" / "textured.obj", force="mesh")
    assert len(mesh.faces) > 1000


@needs_ycb
def test_import_skips_complete_unless_forced(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    raw = tmp_path / "raw"
    import_directory(YCB_DIR, raw, [DICE])
    copies: list[Path] = []
    real_copy = fetch._copy_file
    monkeypatch.setattr(fetch, "_copy_file", lambda s, d: (copies.append(s), real_copy(s, d)))

    assert import_directory(YCB_DIR, raw, [DICE]) == [DICE]
    assert copies == []
    assert import_directory(YCB_DIR, raw, [DICE], force=True, density_kg_m3=900.0) == [DICE]
    assert len(copies) == 3
    assert complete_objects(raw) == [DICE]
    assert not list(raw.glob(".*"))


def _write_plain_meshes(src: Path) -> None:
    """box.stl, ball.ply and a textured cube.obj (with its mtl and texture) in ``src``."""
    src.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(0.1, 0.2, 0.3)).export(src / "box.stl")
    trimesh.creation.icosphere(subdivisions=1, radius=0.05).export(src / "ball.ply")
    obj = trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(file_type="obj")
    (src / "cube.obj").write_text("mtllib mats/cube.mtl\nusemtl red\n" + obj)
    (src / "mats").mkdir()
    (src / "mats" / "cube.mtl").write_text("newmtl red\nmap_Kd -s 1 1 1 ../tex/red.png\n")
    (src / "tex").mkdir()
    (src / "tex" / "red.png").write_bytes(_png_bytes())
    (src / "unrelated.png").write_bytes(_png_bytes())
    (src / "notes.txt").write_text("not a mesh")


def test_import_plain_files_with_density(tmp_path: Path) -> None:
    src, raw = tmp_path / "meshes", tmp_path / "raw"
    _write_plain_meshes(src)

    assert import_directory(src, raw, density_kg_m3=1000.0) == ["ball", "box", "cube"]

    for name, ext in (("ball", "ply"), ("box", "stl"), ("cube", "obj")):
        rec = read_source(raw, name)
        assert rec["mesh"] == f"{name}.{ext}"
        assert rec["mass_kg"] is None and rec["density_kg_m3"] == 1000.0
        mesh = trimesh.load(raw / name / rec["mesh"], force="mesh")
        assert mesh.is_watertight
    assert trimesh.load(raw / "box" / "box.stl").volume == pytest.approx(0.006)
    # The OBJ keeps its material and texture at the paths its mtllib/map_Kd lines name.
    assert (raw / "cube" / "mats" / "cube.mtl").is_file()
    assert (raw / "cube" / "tex" / "red.png").is_file()
    assert not (raw / "cube" / "unrelated.png").exists()


def test_import_mixed_layout_with_src_masses(tmp_path: Path) -> None:
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    ycb = src / "my_can" / "google_16k"
    ycb.mkdir(parents=True)
    (ycb / "textured.obj").write_text(_box_obj())
    (ycb / "textured.mtl").write_text(MTL_TEXT)
    (ycb / "texture_map.png").write_bytes(_png_bytes())
    (src / "masses.csv").write_text("object,mass_kg\nmy_can,0.35\nbox,0.2\n")

    assert import_directory(src, raw, ["my_can", "box", "ball"]) == ["ball", "box", "my_can"]

    assert read_source(raw, "my_can")["mass_kg"] == 0.35
    assert read_source(raw, "my_can")["mesh"] == "google_16k/textured.obj"
    assert read_source(raw, "box")["mass_kg"] == 0.2
    assert read_source(raw, "ball")["density_kg_m3"] == 500.0  # not in masses.csv: density
    assert "cube" not in complete_objects(raw)

    # An explicit masses file wins over src/masses.csv.
    other = tmp_path / "other.csv"
    other.write_text("object,mass_kg\nbox,0.9\n")
    import_directory(src, raw, ["box"], masses_csv=other, force=True)
    assert read_source(raw, "box")["mass_kg"] == 0.9


def test_import_unknown_name(tmp_path: Path) -> None:
    src = tmp_path / "src"
    _write_plain_meshes(src)
    with pytest.raises(GeomprepError, match=r"'?bxo'? not found") as err:
        import_directory(src, tmp_path / "raw", ["bxo"])
    assert "NAME/google_16k/textured.obj" in str(err.value)
    assert complete_objects(tmp_path / "raw") == []


def test_import_empty_directory(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("nothing here")
    with pytest.raises(GeomprepError, match=r"no objects found.*expected"):
        import_directory(tmp_path / "empty", tmp_path / "raw")
    with pytest.raises(GeomprepError, match="not a directory"):
        import_directory(tmp_path / "missing", tmp_path / "raw")


def test_import_invalid_file_name(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    trimesh.creation.box().export(src / "my box.stl")
    with pytest.raises(GeomprepError, match=r"invalid object names.*my box.stl"):
        import_directory(src, tmp_path / "raw")


def test_import_bad_density(tmp_path: Path) -> None:
    src = tmp_path / "src"
    _write_plain_meshes(src)
    with pytest.raises(GeomprepError, match="density"):
        import_directory(src, tmp_path / "raw", density_kg_m3=0.0)


def test_import_crash_midway_then_rerun(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    real_copy = fetch._copy_file
    calls = {"n": 0}

    def flaky_copy(a: Path, b: Path) -> None:
        calls["n"] += 1
        if calls["n"] == 2:  # the cube's mtl, after its obj was copied
            raise OSError(28, "No space left on device")
        real_copy(a, b)

    monkeypatch.setattr(fetch, "_copy_file", flaky_copy)
    with pytest.raises(GeomprepError, match="No space left") as err:
        import_directory(src, raw, ["cube"])
    assert "\n" not in str(err.value)
    _assert_absent(raw, "cube")

    monkeypatch.setattr(fetch, "_copy_file", real_copy)
    assert import_directory(src, raw, ["cube"]) == ["cube"]
    assert complete_objects(raw) == ["cube"]


def test_import_after_hard_crash_leftovers(tmp_path: Path) -> None:
    """A killed process leaves a half object dir and a staging dir: the rerun cleans both."""
    src, raw = tmp_path / "src", tmp_path / "raw"
    _write_plain_meshes(src)
    (raw / "box").mkdir(parents=True)
    (raw / "box" / "box.stl").write_bytes(b"half")
    dead_pid = 2**22 + 12345  # above Linux's pid_max default: no such process
    stage = raw / f".box.tmp-{dead_pid}"
    stage.mkdir()
    (stage / "source.json").write_text(json.dumps({"name": "box"}))
    assert complete_objects(raw) == []

    assert import_directory(src, raw, ["box"]) == ["box"]

    assert complete_objects(raw) == ["box"]
    assert (raw / "box" / "box.stl").read_bytes() == (src / "box.stl").read_bytes()
    assert not stage.exists()
