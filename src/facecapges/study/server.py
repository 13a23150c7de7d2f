"""The study's web server: the ranking page, the media of the current trial, the answer store.

Standard library only (``http.server.ThreadingHTTPServer``). Routes::

    GET  /                         the study page (page/study.html, page/study.js)
    GET  /web/avatar_scene.js      the project's three.js avatar scene module
    GET  /three/...                three.js (npm three 0.187.0, from node_modules)
    GET  /avatar.glb               the study's avatar (or /avatar.vrm, /web/vrm_scene.js, /pixiv/* three-vrm)
    GET  /api/info                 criteria wording, number of clips and of versions (K)
    POST /api/session              {"participant"} → progress; unknown ids are refused
    GET  /api/trial?participant=P&index=i
                                   the current trial: frame rate, length and the media URLs
    GET  /media/P/i/audio.wav | face.json | motion-<position>.json
    POST /api/event                {"participant", "index", "type": "play"}
    POST /api/answer               {"participant", "index", "ranks": {criterion: [rank per position]}}

Blindness: the page only ever learns screen positions. Media are served under the
participant, trial index and position, mapped to the system's file here on the server;
no system name, file name or clip id reaches the browser. Only the current trial of a
participant is served and answered (no going back); every answer is on disk before the
reply goes out (facecapges.study.store), so closing the browser loses nothing and the
same participant id resumes at the first unanswered clip.
"""

from __future__ import annotations

import json
import re
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from facecapges.study.build import AVATAR_FILE, VRM_FILE, Study, media_dir, motion_file
from facecapges.study.store import AnswerError, AnswerStore

PAGE_DIR = Path(__file__).with_name("page")
CONTENT_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
                 ".css": "text/css; charset=utf-8", ".json": "application/json", ".wav": "audio/wav",
                 ".glb": "model/gltf-binary", ".vrm": "model/gltf-binary", ".png": "image/png"}
_MEDIA = re.compile(r"^/media/([^/]+)/(\d+)/(audio\.wav|face\.json|motion-(\d+)\.json)$")
MAX_BODY = 64 * 1024


class HttpError(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


class StudyApp:
    """Everything the handler needs: the study, its answer store and the static folders."""

    def __init__(self, study: Study, on_event: Callable[[str], None] | None = None):
        from facecapges.avatar.render.browser import three_dir, web_dir

        self.study = study
        self.store = AnswerStore(study.responses_dir, study.plan)
        self.three = three_dir()
        self.web = web_dir()
        self.on_event = on_event or (lambda msg: None)
        self._ids = {p.id.lower(): p.id for p in study.plan.participants}

    # ------------------------------------------------------------------ helpers
    def participant(self, raw) -> str:
        pid = self._ids.get(str(raw or "").strip().lower())
        if pid is None:
            raise HttpError(404, f"unknown participant id {str(raw or '').strip()!r}; please check the id you "
                                 "were given")
        return pid

    def current(self, pid: str, index) -> int:
        try:
            i = int(index)
        except (TypeError, ValueError):
            raise HttpError(400, f"bad trial index {index!r}") from None
        st = self.store.state(pid)
        if st["done"]:
            raise HttpError(409, "all clips have been ranked")
        if i != st["next"]:
            raise HttpError(409, f"clip {i + 1} is not the current clip ({st['next'] + 1}); going back is not possible")
        return i

    def info(self) -> dict:
        return {"criteria": self.study.doc["criteria"], "clips": len(self.study.plan.clips),
                "versions": len(self.study.plan.systems), "fps": self.study.doc["fps"],
                "avatar": "vrm" if self.study.doc.get("avatar") == VRM_FILE else "glb"}

    def trial(self, pid: str, i: int) -> dict:
        t = self.study.plan.participant(pid).trials[i]
        meta = self.study.clips[t.clip]
        base = f"/media/{pid}/{i}"
        return {"index": i, "total": len(self.study.plan.clips), "fps": self.study.doc["fps"],
                "frames": meta["frames"], "duration": meta["duration"], "versions": len(t.systems),
                "audio": f"{base}/audio.wav", "face": f"{base}/face.json",
                "motions": [f"{base}/motion-{j}.json" for j in range(len(t.systems))]}

    def media(self, path: str) -> Path | None:
        m = _MEDIA.match(path)
        if not m:
            return None
        pid = self.participant(m.group(1))
        i = self.current(pid, m.group(2))
        t = self.study.plan.participant(pid).trials[i]
        if m.group(3) == "audio.wav":
            return media_dir(self.study.dir, t.clip) / "audio.wav"
        if m.group(3) == "face.json":
            return media_dir(self.study.dir, t.clip) / "face.json"
        j = int(m.group(4))
        if j >= len(t.systems):
            raise HttpError(404, "no such position")
        return motion_file(self.study.dir, t.clip, t.systems[j])

    def static(self, path: str) -> Path | None:
        if path in ("/", "/index.html"):
            return PAGE_DIR / "study.html"
        if path == "/avatar.glb":
            return self.study.dir / AVATAR_FILE
        if path == "/web/avatar_scene.js":
            return self.web / "avatar_scene.js"
        if path == "/avatar.vrm":
            return self.study.dir / VRM_FILE
        if path == "/web/vrm_scene.js":
            return self.web / "vrm_scene.js"
        for prefix, root in (("/page/", PAGE_DIR), ("/three/", self.three), ("/pixiv/", self.three.parent / "@pixiv")):
            if path.startswith(prefix):
                full = (root / path[len(prefix):]).resolve()
                if root.resolve() in full.parents and full.is_file():
                    return full
                return None
        return None

    # ------------------------------------------------------------------ API
    def get(self, path: str, query: dict) -> tuple[object, Path | None]:
        if path == "/api/info":
            return self.info(), None
        if path == "/api/trial":
            pid = self.participant(query.get("participant", [""])[0])
            return self.trial(pid, self.current(pid, query.get("index", [""])[0])), None
        f = self.media(path) or self.static(path)
        if f is None or not f.is_file():
            raise HttpError(404, f"not found: {path}")
        return None, f

    def post(self, path: str, body: dict) -> dict:
        pid = self.participant(body.get("participant"))
        try:
            if path == "/api/session":
                st = self.store.session(pid)
                self.on_event(f"{pid}: {'resumed at' if st['next'] else 'started,'} clip {st['next'] + 1} of "
                              f"{st['total']}" if not st["done"] else f"{pid}: came back after finishing")
                return st
            if path == "/api/event":
                i = self.current(pid, body.get("index"))
                self.store.event(pid, i, str(body.get("type")))
                return {"ok": True}
            if path == "/api/answer":
                i = self.current(pid, body.get("index"))
                st = self.store.answer(pid, i, body.get("ranks"))
                self.on_event(f"{pid}: ranked clip {i + 1} of {st['total']}" + (" — finished" if st["done"] else ""))
                return st
        except AnswerError as exc:
            raise HttpError(409, str(exc)) from None
        raise HttpError(404, f"not found: {path}")


class _Handler(BaseHTTPRequestHandler):
    app: StudyApp
    server_version = "facecapges-study"

    def log_message(self, *args) -> None:  # the app reports what matters
        pass

    def _send(self, status: int, data: bytes, ctype: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(data)

    def _json(self, status: int, doc) -> None:
        self._send(status, json.dumps(doc).encode("utf-8"), "application/json")

    def do_GET(self) -> None:
        url = urlsplit(self.path)
        try:
            doc, f = self.app.get(url.path, parse_qs(url.query))
        except HttpError as exc:
            return self._json(exc.status, {"error": str(exc)})
        if f is None:
            return self._json(200, doc)
        self._send(200, f.read_bytes(), CONTENT_TYPES.get(f.suffix, "application/octet-stream"))

    do_HEAD = do_GET

    def do_POST(self) -> None:
        try:
            n = int(self.headers.get("Content-Length") or 0)
            if n > MAX_BODY:
                raise HttpError(413, "request too large")
            try:
                body = json.loads(self.rfile.read(n) or b"{}")
            except (json.JSONDecodeError, UnicodeDecodeError):
                raise HttpError(400, "request body is not JSON") from None
            if not isinstance(body, dict):
                raise HttpError(400, "request body must be a JSON object")
            doc = self.app.post(urlsplit(self.path).path, body)
        except HttpError as exc:
            return self._json(exc.status, {"error": str(exc)})
        self._json(200, doc)


def make_server(study: Study, host: str = "127.0.0.1", port: int = 8770,
                on_event: Callable[[str], None] | None = None) -> ThreadingHTTPServer:
    """An HTTP server for ``study`` bound to ``host:port`` (port 0: any free port); not yet serving."""
    handler = type("StudyHandler", (_Handler,), {"app": StudyApp(study, on_event)})
    server = ThreadingHTTPServer((host, port), handler)
    server.daemon_threads = True
    return server


def serve_in_thread(server: ThreadingHTTPServer) -> threading.Thread:
    """Start ``server.serve_forever`` in a daemon thread (tests, embedding)."""
    t = threading.Thread(target=server.serve_forever, daemon=True)
    t.start()
    return t
