"""`fracture view`'s server and the `impact` / `bake --preview` command-line fixes (no browser)."""

from __future__ import annotations

import json
import os
import urllib.error
import urllib.request

import numpy as np
import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.errors import FractureError, InputError
from fracture_cli.runtime.format import RuntimeData, write_runtime
from fracture_cli.view import server as view_server
from fracture_cli.view.assets import ViewSource, list_assets, resolve_source, served_file


def _row_of_boxes(folder, stem="row", p=3):
    """A tiny bake: p unit boxes in a row (fragments GLB) and a runtime file that splits them."""
    trimesh = pytest.importorskip("trimesh")
    from fracture_cli.io.gltf import Primitive, glb_bytes
    from fracture_cli.types import Material

    meshes = []
    for j in range(p):
        box = trimesh.creation.box(extents=(1, 1, 1))
        origin = np.array([2.0 * j, 0.0, 0.0])
        meshes.append((f"fragment_{j:03d}", [Primitive(box.vertices, box.vertex_normals, None, box.faces, 0)], origin))
    (folder / f"{stem}.glb").write_bytes(glb_bytes(meshes, (Material("outer"),)))
    data = RuntimeData(sites=np.array([[2.0 * j, 0.6, 0.0] for j in range(p)], np.float32),
                       B=np.ones((p, 1, 1), np.float32),
                       W=np.array([[[1.0], [0.0], [-1.0]]], np.float32)[:, :p],
                       edges=np.array([[j, j + 1] for j in range(p - 1)], np.int32),
                       edge_areas=np.ones(p - 1, np.float32),
                       fragment_names=tuple(f"fragment_{j:03d}" for j in range(p)), default_threshold=0.5)
    write_runtime(data, folder / f"{stem}.fracture.json")
    return folder / f"{stem}.fracture.json"


# ---------------------------------------------------------------- impact


def test_impact_group_names_match_the_written_glb(tmp_path):
    from fracture_cli.io.gltf import read_glb_chunks

    runtime = _row_of_boxes(tmp_path)
    out = tmp_path / "broken.glb"
    result = CliRunner().invoke(cli, ["impact", str(runtime), "--point", "4", "0.5", "0", "--impulse", "0", "-1", "0",
                                      "-o", str(out)])
    assert result.exit_code == 0, result.output
    printed = [line.split(":")[0] for line in result.stdout.splitlines()[1:]]
    doc, _ = read_glb_chunks(str(out))
    assert printed == [doc["nodes"][i]["name"] for i in doc["scenes"][0]["nodes"]]
    assert printed == ["group_000", "group_001", "group_002"]
    as_json = CliRunner().invoke(cli, ["impact", str(runtime), "--point", "4", "0.5", "0", "--impulse", "0", "-1", "0",
                                       "--json"])
    body = json.loads(as_json.stdout)
    assert body["group_names"] == printed and body["groups"] == [["fragment_000"], ["fragment_001"], ["fragment_002"]]
    assert "warning" not in as_json.stderr


def test_impact_warns_about_a_far_point_and_its_help_says_what_it_writes(tmp_path):
    runtime = _row_of_boxes(tmp_path)
    far = CliRunner().invoke(cli, ["impact", str(runtime), "--point", "100", "100", "100", "--impulse", "0", "-1", "0"])
    assert far.exit_code == 0
    assert "warning: the point is" in far.stderr and "diagonal" in far.stderr
    quiet = CliRunner().invoke(cli, ["impact", str(runtime), "--point", "100", "100", "100", "--impulse", "0", "-1",
                                     "0", "--warn-distance", "1000"])
    assert "warning" not in quiet.stderr
    help_text = " ".join(CliRunner().invoke(cli, ["impact", "--help"]).stdout.split())
    assert "one node per group, named group_###" in help_text
    assert "one mesh per group" not in help_text


# ---------------------------------------------------------------- bake --preview-size, stale previews


class _FakeBake:
    """Stands in for the pipeline: the CLI logic around it is what is tested (the preview itself is
    rendered into the output set by the bake: tests/test_outputs.py and tests/test_preview.py)."""

    def __init__(self):
        self.previews = []

    def bake(self, path, out_dir, recipe, cache_dir=None, jobs=None, preview_size=None, started=None):
        from fracture_cli.pipeline.bake import BakeResult

        self.previews.append(preview_size)
        report = {"counts": {"fragments": 1, "modes": 1, "tets": 1}, "checks": {"volume_error": 0.0},
                  "seconds": {"load": 0.0}}
        return BakeResult(report=report, outputs=())


@pytest.fixture
def fake_bake(monkeypatch):
    import fracture_cli.pipeline.bake

    fake = _FakeBake()
    monkeypatch.setattr(fracture_cli.pipeline.bake, "bake", fake.bake)
    return fake


def test_bake_preview_size_reaches_the_bake(tmp_path, fake_bake):
    asset = tmp_path / "thing.glb"
    asset.write_bytes(b"")
    out = tmp_path / "out"
    for extra, size in ((["--preview-size", "2400", "1500"], (2400, 1500)), ([], None),
                        (["--preview"], (1600, 1000))):
        result = CliRunner().invoke(cli, ["bake", str(asset), "-o", str(out), *extra, "-q"])
        assert result.exit_code == 0, result.output
        assert fake_bake.previews[-1] == size
    bad = CliRunner().invoke(cli, ["bake", str(asset), "-o", str(out), "--preview-size", "10", "10"])
    assert bad.exit_code == 2 and "--preview-size 10 10 is out of range" in bad.output


# ---------------------------------------------------------------- the view server


def test_resolve_source(tmp_path):
    runtime = _row_of_boxes(tmp_path)
    assert resolve_source(str(tmp_path)) == ViewSource(folder=str(tmp_path))
    assert resolve_source(str(runtime)) == ViewSource(folder=str(tmp_path), stem="row")
    assert resolve_source(str(tmp_path / "row.glb")).stem == "row"
    with pytest.raises(InputError, match="not found"):
        resolve_source(str(tmp_path / "nope"))
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="not a bake output"):
        resolve_source(str(tmp_path / "notes.txt"))
    (tmp_path / "lonely.glb").write_bytes(b"")
    with pytest.raises(InputError, match="no lonely.fracture.json"):
        resolve_source(str(tmp_path / "lonely.glb"))


def test_served_files_are_only_bake_outputs(tmp_path):
    _row_of_boxes(tmp_path)
    (tmp_path / "secret.txt").write_text("x")
    source = ViewSource(folder=str(tmp_path))
    assert served_file(source, "row.glb") == str(tmp_path / "row.glb")
    assert served_file(source, "row.fracture.bin") is not None
    for name in ("secret.txt", "../row.glb", "sub/row.glb", ".row.glb", "", "missing.glb"):
        assert served_file(source, name) is None, name
    assert served_file(ViewSource(folder=str(tmp_path), stem="other"), "row.glb") is None


def test_asset_state_changes_when_a_bake_rewrites_files(tmp_path):
    _row_of_boxes(tmp_path)
    _row_of_boxes(tmp_path, stem="another")
    source = ViewSource(folder=str(tmp_path))
    first = list_assets(source)
    assert [a["stem"] for a in first] == ["another", "row"]
    assert first[1]["missing"] == [] and first[1]["files"]["glb"] == "row.glb"
    stat = os.stat(tmp_path / "row.glb")
    os.utime(tmp_path / "row.glb", ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    second = list_assets(source)
    assert second[1]["version"] != first[1]["version"] and second[0]["version"] == first[0]["version"]
    os.remove(tmp_path / "row.fracture.bin")
    assert list_assets(source)[1]["missing"] == ["row.fracture.bin"]


def _get(url):
    try:
        with urllib.request.urlopen(url, timeout=10) as response:
            return response.status, response.read(), response.headers
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read(), exc.headers


def test_server_routes(tmp_path, monkeypatch):
    _row_of_boxes(tmp_path)
    monkeypatch.setattr(view_server, "check_vendor", lambda: None)  # the page's vendor files are not needed here
    with view_server.ViewServer(ViewSource(folder=str(tmp_path)), view_server.ViewOptions(port=0)) as srv:
        assert srv.url.startswith("http://127.0.0.1:")
        status, body, _ = _get(srv.url + "api/state")
        state = json.loads(body)
        assert status == 200 and [a["stem"] for a in state["assets"]] == ["row"]
        status, body, headers = _get(srv.url + "files/row.fracture.bin")
        assert status == 200 and body == (tmp_path / "row.fracture.bin").read_bytes()
        assert headers["Cache-Control"] == "no-store"
        status, body, headers = _get(srv.url)
        assert status == 200 and b'type="importmap"' in body and headers["Content-Type"] == "text/html"
        assert b"https://" not in body and b"http://" not in body  # nothing from a CDN
        assert _get(srv.url + "static/app.js")[0] == 200
        for bad in ("files/../row.glb", "files/%2e%2e%2fsecret", "static/../server.py", "static/%2e%2e/server.py",
                    "nothing"):
            assert _get(srv.url + bad)[0] == 404, bad


def test_missing_web_files_is_one_clear_error(tmp_path, monkeypatch):
    monkeypatch.setattr(view_server, "VENDOR_DIR", str(tmp_path / "vendor"))
    with pytest.raises(FractureError, match="run 'make web'"):
        view_server.check_vendor()
    _row_of_boxes(tmp_path)
    result = CliRunner().invoke(cli, ["view", str(tmp_path), "--no-browser", "--port", "0"])
    assert result.exit_code == 1
    assert result.stderr.strip().splitlines() == [result.stderr.strip()]  # one line
    assert "web files are not built" in result.stderr


def test_loopback_detection():
    assert view_server.is_loopback("127.0.0.1") and view_server.is_loopback("::1")
    assert view_server.is_loopback("localhost") and view_server.is_loopback("127.0.0.2")
    assert not view_server.is_loopback("0.0.0.0") and not view_server.is_loopback("192.168.1.4")


def test_static_page_imports_only_local_modules():
    """The page works offline: every import is relative or through the import map to vendor/."""
    import re

    static = view_server.STATIC_DIR
    for name in os.listdir(static):
        if not name.endswith(".js"):
            continue
        with open(os.path.join(static, name), encoding="utf-8") as fh:
            text = fh.read()
        for spec in re.findall(r"^import .* from '([^']+)';", text, re.MULTILINE):
            assert spec.startswith(("./", "three/addons/")) or spec == "three", (name, spec)
        assert "http://" not in text and "https://" not in text, name


def _get_with_host(srv, path: str, host: str | None) -> int:
    import http.client

    bound, port = srv.httpd.server_address[:2]
    conn = http.client.HTTPConnection(bound, port, timeout=10)
    try:
        conn.putrequest("GET", path, skip_host=True)
        if host is not None:
            conn.putheader("Host", host)
        conn.endheaders()
        response = conn.getresponse()
        response.read()
        return response.status
    finally:
        conn.close()


def test_host_header_must_name_the_server(tmp_path, monkeypatch):
    """DNS rebinding: a page of another site re-pointed at 127.0.0.1 sends its own name and is refused."""
    _row_of_boxes(tmp_path)
    monkeypatch.setattr(view_server, "check_vendor", lambda: None)
    with view_server.ViewServer(ViewSource(folder=str(tmp_path)), view_server.ViewOptions(port=0)) as srv:
        port = srv.httpd.server_address[1]
        for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"LOCALHOST.:{port}"):
            assert _get_with_host(srv, "/files/row.glb", host) == 200, host
        for host in (f"evil.example:{port}", f"127.0.0.1.nip.io:{port}", f"127.0.0.1:{port + 1}", "127.0.0.1",
                     f"192.168.1.4:{port}", "", None, f"localhost:{port}:1"):
            assert _get_with_host(srv, "/files/row.glb", host) == 403, host
            assert _get_with_host(srv, "/api/state", host) == 403, host


def test_host_allowed_for_other_interfaces():
    assert view_server.host_allowed("192.168.1.4:8765", "0.0.0.0", 8765)
    assert view_server.host_allowed("[::1]:8765", "::", 8765) and view_server.host_allowed("[::1]:80", "::1", 80)
    assert not view_server.host_allowed("attacker.example:8765", "0.0.0.0", 8765)
    assert view_server.host_allowed("box.lan:8765", "box.lan", 8765)
    assert not view_server.host_allowed("[::1:8765", "::1", 8765)


def test_symlinks_out_of_the_folder_are_not_served(tmp_path, monkeypatch):
    folder = tmp_path / "bake"
    folder.mkdir()
    _row_of_boxes(folder)
    (tmp_path / "secret.glb").write_bytes(b"secret")
    os.symlink(tmp_path / "secret.glb", folder / "leak.glb")
    os.symlink(folder / "row.glb", folder / "alias.glb")  # a link that stays inside is fine
    source = ViewSource(folder=str(folder))
    assert served_file(source, "leak.glb") is None
    assert served_file(source, "alias.glb") == str(folder / "alias.glb")
    monkeypatch.setattr(view_server, "check_vendor", lambda: None)
    static = tmp_path / "static"
    static.mkdir()
    (static / "app.js").write_text("// page")
    os.symlink(tmp_path / "secret.glb", static / "leak.js")
    monkeypatch.setattr(view_server, "STATIC_DIR", str(static))
    with view_server.ViewServer(source, view_server.ViewOptions(port=0)) as srv:
        assert _get(srv.url + "files/leak.glb")[0] == 404
        assert _get(srv.url + "static/leak.js")[0] == 404
        assert _get(srv.url + "static/app.js")[0] == 200
        status, body, _ = _get(srv.url + "files/alias.glb")
        assert status == 200 and body == (folder / "row.glb").read_bytes()
