"""Static files over HTTP, for every server of the project: the viewer and VRM viewer
(:mod:`facecapges.runtime.outputs.viewer`), the renderer's page server for headless Chromium
(:mod:`facecapges.avatar.render.browser`) and the study server (:mod:`facecapges.study.server`).

* :data:`CONTENT_SECURITY_POLICY` — the policy every page we serve carries.
* :func:`content_type` — the one content-type table: the standard library's built-in table
  (``mimetypes.MimeTypes()``, the same on every machine: ``/etc/mime.types`` is not read)
  with :data:`CONTENT_TYPES` on top where it is silent or says otherwise; text is UTF-8.
* :func:`file_under` — a URL path's file inside a folder: resolved (symbolic links
  followed), refused when it leaves the folder (``..``, links out), is no regular file
  or is a name the file system cannot hold (too long, NUL).
* :func:`locate` / :func:`find` — what a request path names in a route table (exact paths →
  bytes or a file, ``/prefix/`` → a folder), and its body and type; :func:`page_headers` — the headers of a reply:
  type, length, no caching (``no-store``), the CSP.
* :class:`PageHandler` — an ``http.server`` handler that sends replies with those headers.

Nothing here decodes ``%xx`` escapes: a path is looked up as sent.
"""

from __future__ import annotations

import mimetypes
from collections.abc import Mapping
from http.server import BaseHTTPRequestHandler
from pathlib import Path, PurePosixPath

__all__ = [
    "CONTENT_SECURITY_POLICY",
    "CONTENT_TYPES",
    "NOT_FOUND",
    "PageHandler",
    "content_type",
    "file_under",
    "find",
    "locate",
    "page_headers",
    "request_path",
]

# The Content-Security-Policy of every page we serve (renderer, live viewer, study): scripts, styles,
# data and sockets from the serving origin only ('self'; in Chromium it covers ws:// to the same
# host), embedded images/buffers as data: or blob: URLs. A crafted avatar or page cannot make the
# browser reach anything else. Inline scripts are allowed: the pages' import maps and render loops
# are inline, and nothing a user supplies is ever put into a page.
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; media-src 'self' data: blob:; connect-src 'self' data: blob:; "
    "font-src 'self' data:; worker-src 'self' blob:; object-src 'none'; base-uri 'none'; "
    "form-action 'self'; frame-ancestors 'none'"
)

# Where the standard library's built-in table is silent or differs (Python 3.11 says
# application/javascript and audio/x-wav): JavaScript per RFC 9239, WAV per RFC 2361, and the
# glTF family (VRM avatars and VRMA animations are binary glTF).
CONTENT_TYPES: dict[str, str] = {
    ".js": "text/javascript",
    ".mjs": "text/javascript",
    ".wav": "audio/wav",
    ".glb": "model/gltf-binary",
    ".gltf": "model/gltf+json",
    ".vrm": "model/gltf-binary",
    ".vrma": "model/gltf-binary",
}
OCTET_STREAM = "application/octet-stream"
NOT_FOUND = b"not found\n"
_BUILT_IN = mimetypes.MimeTypes().types_map[True]  # built-in defaults only


def content_type(name: str) -> str:
    """The ``Content-Type`` of a file (or URL path) by its suffix; ``application/octet-stream`` if unknown."""
    suffix = PurePosixPath(name).suffix.lower()
    ctype = CONTENT_TYPES.get(suffix) or _BUILT_IN.get(suffix) or OCTET_STREAM
    return f"{ctype}; charset=utf-8" if ctype.startswith("text/") else ctype


def request_path(target: str) -> str:
    """The path of a request target: without its ``?query`` and ``#fragment``."""
    return target.split("?", 1)[0].split("#", 1)[0]


def file_under(root: Path, rel: str) -> Path | None:
    """The regular file ``rel`` names inside ``root``, or None (outside it, missing, impossible)."""
    try:  # a name the file system cannot hold (too long, NUL) is simply not there
        base = root.resolve()
        full = (base / rel).resolve()  # an absolute rel (a doubled slash) is taken as it is
        return full if base in full.parents and full.is_file() else None
    except (OSError, ValueError):
        return None


Routes = Mapping[str, "bytes | Path"]


def locate(routes: Routes, path: str) -> bytes | Path | None:
    """What ``path`` names in ``routes``: its bytes, its file, or None (a 404).

    A key ending in ``/`` serves the folder it maps to (the longest such prefix of ``path``
    decides, :func:`file_under`); any other key serves its bytes or its file at that exact path."""
    target = None if path.endswith("/") else routes.get(path)
    if isinstance(target, (bytes, bytearray)):
        return bytes(target)
    if isinstance(target, Path):
        return target if target.is_file() else None
    prefixes = [k for k in routes if k.endswith("/") and path.startswith(k)]
    if not prefixes:
        return None
    prefix = max(prefixes, key=len)
    root = routes[prefix]
    return file_under(root, path[len(prefix) :]) if isinstance(root, Path) else None


def find(routes: Routes, path: str) -> tuple[bytes, str] | None:
    """(body, content type) of ``path`` in ``routes`` (:func:`locate`), or None (a 404).

    The type comes from the file's name, for bytes from the path's."""
    found = locate(routes, path)
    if isinstance(found, bytes):
        return found, content_type(path)
    return _read(found)


def _read(f: Path | None) -> tuple[bytes, str] | None:
    if f is None:
        return None
    try:
        return f.read_bytes(), content_type(f.name)
    except OSError:  # unreadable, or gone since it was found
        return None


def page_headers(ctype: str, length: int) -> list[tuple[str, str]]:
    """The headers of every reply we serve: its type and length, never cached, the CSP."""
    return [
        ("Content-Type", ctype),
        ("Content-Length", str(length)),
        ("Cache-Control", "no-store"),
        ("Content-Security-Policy", CONTENT_SECURITY_POLICY),
    ]


class PageHandler(BaseHTTPRequestHandler):
    """``http.server`` handler base: :meth:`send_page` replies with :func:`page_headers`; no request log."""

    def log_message(self, *args) -> None:  # the servers report what matters themselves
        pass

    def send_page(self, status: int, body: bytes, ctype: str) -> None:
        """One reply: status, :func:`page_headers`, then the body (none for ``HEAD``)."""
        self.send_response(status)
        for name, value in page_headers(ctype, len(body)):
            self.send_header(name, value)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def send_not_found(self) -> None:
        self.send_page(404, NOT_FOUND, content_type("x.txt"))
