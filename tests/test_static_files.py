"""io/static_files: the one content-type table, paths kept inside their folder, the route table, the headers."""

from __future__ import annotations

import os
import threading
import urllib.error
import urllib.request
from http.server import ThreadingHTTPServer

import pytest

from facecapges.io.static_files import (
    CONTENT_SECURITY_POLICY,
    NOT_FOUND,
    PageHandler,
    content_type,
    file_under,
    find,
    locate,
    page_headers,
    request_path,
)


@pytest.mark.parametrize(("name", "want"), [
    ("viewer.html", "text/html; charset=utf-8"),
    ("three.module.js", "text/javascript; charset=utf-8"),
    ("x.MJS", "text/javascript; charset=utf-8"),
    ("style.css", "text/css; charset=utf-8"),
    ("layout.json", "application/json"),
    ("audio.wav", "audio/wav"),
    ("avatar.glb", "model/gltf-binary"),
    ("avatar.vrm", "model/gltf-binary"),
    ("anim.vrma", "model/gltf-binary"),
    ("scene.gltf", "model/gltf+json"),
    ("shot.png", "image/png"),
    ("decoder.wasm", "application/wasm"),
    ("/web/a.b/noext", "application/octet-stream"),
    ("weird.zzz", "application/octet-stream"),
])
def test_one_content_type_table(name, want):
    assert content_type(name) == want


def test_request_path_drops_query_and_fragment():
    assert request_path("/avatar.glb?x=1#y") == "/avatar.glb"
    assert request_path("/a#b?c") == "/a"


def test_file_under_keeps_paths_inside_the_folder(tmp_path):
    root = tmp_path / "root"
    (root / "sub").mkdir(parents=True)
    (root / "sub" / "a.js").write_text("x")
    (tmp_path / "secret.txt").write_text("secret")
    os.symlink(tmp_path / "secret.txt", root / "link.txt")
    assert file_under(root, "sub/a.js") == (root / "sub" / "a.js").resolve()
    for bad in ("../secret.txt", "sub/../../secret.txt", "link.txt", "sub", "", "/", "missing.js",
                "a" * 5000, "b/" * 3000 + "c.js", "x\0y", "%2e%2e/secret.txt",
                "/sub/a.js"):  # absolute: not relative to the folder
        assert file_under(root, bad) is None, bad


def test_find_exact_routes_then_the_longest_folder(tmp_path):
    (tmp_path / "web" / "deep").mkdir(parents=True)
    (tmp_path / "web" / "viewer.html").write_text("<html>")
    (tmp_path / "web" / "deep" / "x.js").write_text("js")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "x.js").write_text("other")
    page = tmp_path / "web" / "viewer.html"
    routes = {"/web/": tmp_path / "web", "/web/deep/": tmp_path / "other", "/avatar.vrm": b"glTF",
              "/layout.json": b"{}", "/index.html": page}
    assert find(routes, "/avatar.vrm") == (b"glTF", "model/gltf-binary")
    assert find(routes, "/layout.json") == (b"{}", "application/json")
    assert find(routes, "/index.html") == (b"<html>", "text/html; charset=utf-8")
    assert find(routes, "/web/viewer.html") == (b"<html>", "text/html; charset=utf-8")
    assert find(routes, "/web/deep/x.js") == (b"other", "text/javascript; charset=utf-8")  # the longest prefix
    for missing in ("/web/", "/web/../web/viewer.html/..", "/web/../../etc/passwd", "/nothing", "/", "/avatar.glb",
                    "/web/deep/../viewer.html"):
        assert find(routes, missing) is None, missing
    assert find({"/gone.html": tmp_path / "gone.html"}, "/gone.html") is None
    assert locate(routes, "/index.html") == page and locate(routes, "/avatar.vrm") == b"glTF"
    assert locate(routes, "/web/deep/x.js") == (tmp_path / "other" / "x.js").resolve()


def test_page_headers_never_cache_and_carry_the_csp():
    assert page_headers("text/html; charset=utf-8", 12) == [
        ("Content-Type", "text/html; charset=utf-8"),
        ("Content-Length", "12"),
        ("Cache-Control", "no-store"),
        ("Content-Security-Policy", CONTENT_SECURITY_POLICY),
    ]
    assert "default-src 'self'" in CONTENT_SECURITY_POLICY and "object-src 'none'" in CONTENT_SECURITY_POLICY


def test_page_handler_replies_with_those_headers(tmp_path):
    class Handler(PageHandler):
        def do_GET(self):
            if self.path == "/a.json":
                return self.send_page(200, b"{}", content_type("a.json"))
            self.send_not_found()

        do_HEAD = do_GET

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}"
    try:
        with urllib.request.urlopen(base + "/a.json", timeout=10) as r:
            assert r.read() == b"{}" and r.headers["Content-Type"] == "application/json"
            assert r.headers["Cache-Control"] == "no-store"
            assert r.headers["Content-Security-Policy"] == CONTENT_SECURITY_POLICY
        with urllib.request.urlopen(urllib.request.Request(base + "/a.json", method="HEAD"), timeout=10) as r:
            assert r.read() == b"" and r.headers["Content-Length"] == "2"
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(base + "/b", timeout=10)
        assert e.value.code == 404 and e.value.read() == NOT_FOUND
        assert e.value.headers["Content-Security-Policy"] == CONTENT_SECURITY_POLICY
    finally:
        server.shutdown()
        server.server_close()
