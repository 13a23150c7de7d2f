"""The study's web server: the ranking page, the media of the current trial, the answer store.

Standard library only (``http.server.ThreadingHTTPServer``). Routes::

    GET  /                         the study page (page/study.html, page/study.js);
                                   a participant opens his invitation link /?invite=TOKEN
    GET  /web/avatar_scene.js      the project's three.js avatar scene module
    GET  /three/...                three.js (npm three 0.187.0, from node_modules)
    GET  /avatar.glb               the study's avatar (or /avatar.vrm, /web/vrm_scene.js, /pixiv/* three-vrm)
    GET  /api/info                 criteria wording (English and Chinese), page language,
                                   number of clips and of versions (K)
    POST /api/session              {"token"} → progress; a missing or unknown token is refused
    GET  /api/trial?token=T&index=i
                                   the current trial: frame rate, length and the media URLs
    GET  /media/T/i/audio.wav | face.json | motion-<position>.json
    POST /api/event                {"token", "index", "type": "play"}
    POST /api/answer               {"token", "index", "ranks": {criterion: [rank per position]}}

Credentials: the invitation token of a participant (facecapges.study.build) is the only
thing that identifies him; participant ids are never accepted on their own (HTTP 401),
so nobody can answer for, or lock out, another participant by guessing ``P07``.

Blindness: the page only ever learns screen positions. Media are served under the
token, trial index and position, mapped to the system's file here on the server;
no system name, file name or clip id reaches the browser. Only the current trial of a
participant is served and answered (no going back); every answer is on disk before the
reply goes out (facecapges.study.store), so closing the browser loses nothing and the
same invitation link resumes at the first unanswered clip.

Bounds: a request body must state its ``Content-Length`` (411 without, 400 when it is
not a number ≥ 0, 413 above :data:`MAX_BODY`); a connection that sends nothing for
:data:`SOCKET_TIMEOUT` seconds is closed, and one whose request (head and body) has not
all arrived :data:`REQUEST_DEADLINE` seconds after the server began waiting for it is cut
(a client trickling a header line every few seconds holds no slot for long); at most
:data:`MAX_CONNECTIONS` are open at once, :data:`MAX_PER_ADDRESS` of them from one client
address. When a new connection would exceed either, the connection in its way (of its address,
or of all) that has waited the longest for its request — a trickler, or an idle keep-alive — is
closed to make room; only when every one in the way is being answered is the newcomer answered
503 and closed. So clients that trickle headers and reopen at once, from any number of
addresses, cannot keep a participant out. JSON nested deeper than Python can parse
is a 400; a damaged answer file is a 500 naming the file, logged once.
"""

from __future__ import annotations

import hmac
import json
import re
import socket
import threading
import time
from collections.abc import Callable
from http.server import ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from facecapges.errors import echo
from facecapges.io.static_files import PageHandler, content_type, locate
from facecapges.study.build import AVATAR_FILE, VRM_FILE, Study, media_dir, motion_file
from facecapges.study.design import ParticipantPlan
from facecapges.study.options import StudyServeOptions
from facecapges.study.store import AnswerError, AnswerStore, DamagedFileError, LimitError

PAGE_DIR = Path(__file__).with_name("page")
_MEDIA = re.compile(r"^/media/([^/]+)/(\d+)/(audio\.wav|face\.json|motion-(\d+)\.json)$")
MAX_BODY = 64 * 1024
SOCKET_TIMEOUT = 15.0  # seconds a connection may stay silent (headers, body, keep-alive)
MAX_CONNECTIONS = 64  # connections open at once (module docs: the longest-waiting makes room)
MAX_PER_ADDRESS = 16  # of those, from one client address (a lab behind one NAT: its idle ones make room)
REQUEST_DEADLINE = 30.0  # seconds from a request's first wait to its whole head and body (a trickle is cut)
LANGUAGES = ("en", "zh")


class HttpError(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


class StudyApp:
    """Everything the handler needs: the study, its answer store and the static folders."""

    def __init__(self, study: Study, on_event: Callable[[str], None] | None = None, language: str = "en"):
        from facecapges.avatar.render.browser import three_dir, web_dir

        self.study = study
        self.store = AnswerStore(study.responses_dir, study.plan)
        self.three = three_dir()
        self.web = web_dir()
        self.routes: dict[str, bytes | Path] = {  # the page, the avatar and the scripts (io.static_files)
            "/page/": PAGE_DIR,
            "/three/": self.three,
            "/pixiv/": self.three.parent / "@pixiv",
            "/avatar.glb": study.dir / AVATAR_FILE,
            "/avatar.vrm": study.dir / VRM_FILE,
            "/web/avatar_scene.js": self.web / "avatar_scene.js",
            "/web/vrm_scene.js": self.web / "vrm_scene.js",
        }
        self.on_event = on_event or (lambda msg: None)
        self.language = language if language in LANGUAGES else "en"
        self._tokens = [(p.token.encode("utf-8"), p.id) for p in study.plan.participants if p.token]
        self._damaged: set[str] = set()

    # ------------------------------------------------------------------ helpers
    def participant(self, raw) -> str:
        """The participant whose invitation token ``raw`` is (401 otherwise)."""
        token = str(raw or "").strip().encode("utf-8", "replace")
        if not token:
            raise HttpError(401, "an invitation token is required; please open the link you were given")
        pid = None
        for known, p in self._tokens:  # compare every token, in constant time each
            if hmac.compare_digest(known, token):
                pid = p
        if pid is None:
            raise HttpError(401, "unknown invitation; please open the exact link you were given")
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
        return {
            "criteria": self.study.doc["criteria"],
            "clips": len(self.study.plan.clips),
            "versions": len(self.study.plan.systems),
            "fps": self.study.doc["fps"],
            "avatar": "vrm" if self.study.doc.get("avatar") == VRM_FILE else "glb",
            "language": self.language,
            "languages": list(LANGUAGES),
        }

    def _plan(self, pid: str) -> ParticipantPlan:
        plan = self.study.plan.participant(pid)
        if plan is None:  # a token always names a planned participant
            raise HttpError(404, f"participant {pid} is not in the study plan")
        return plan

    def trial(self, pid: str, i: int) -> dict:
        t = self._plan(pid).trials[i]
        meta = self.study.clips[t.clip]
        base = f"/media/{self._plan(pid).token}/{i}"
        return {
            "index": i,
            "total": len(self.study.plan.clips),
            "fps": self.study.doc["fps"],
            "frames": meta["frames"],
            "duration": meta["duration"],
            "versions": len(t.systems),
            "audio": f"{base}/audio.wav",
            "face": f"{base}/face.json",
            "motions": [f"{base}/motion-{j}.json" for j in range(len(t.systems))],
        }

    def media(self, path: str) -> Path | None:
        m = _MEDIA.match(path)
        if not m:
            return None
        pid = self.participant(m.group(1))
        i = self.current(pid, m.group(2))
        t = self._plan(pid).trials[i]
        if m.group(3) == "audio.wav":
            return media_dir(self.study.dir, t.clip) / "audio.wav"
        if m.group(3) == "face.json":
            return media_dir(self.study.dir, t.clip) / "face.json"
        j = int(m.group(4))
        if j >= len(t.systems):
            raise HttpError(404, "no such position")
        return motion_file(self.study.dir, t.clip, t.systems[j])

    def static(self, path: str) -> Path | None:
        found = locate(self.routes, "/page/study.html" if path in ("/", "/index.html") else path)
        return found if isinstance(found, Path) else None

    # ------------------------------------------------------------------ API
    def get(self, path: str, query: dict) -> tuple[object, Path | None]:
        if path == "/api/info":
            return self.info(), None
        try:
            if path == "/api/trial":
                pid = self.participant(query.get("token", [""])[0])
                return self.trial(pid, self.current(pid, query.get("index", [""])[0])), None
            f = self.media(path) or self.static(path)
        except DamagedFileError as exc:
            raise self._damaged_file(exc) from None
        if f is None or not f.is_file():
            raise HttpError(404, f"not found: {path[:200]}")
        return None, f

    def _damaged_file(self, exc: DamagedFileError) -> HttpError:
        if str(exc) not in self._damaged:  # one line per damaged file, not one per request
            self._damaged.add(str(exc))
            self.on_event(f"error: {exc}")
        return HttpError(
            500,
            "your answers cannot be recorded right now (the study's answer file is damaged); "
            "please tell the person running the study",
        )

    def post(self, path: str, body: dict) -> dict:
        if path not in ("/api/session", "/api/event", "/api/answer"):
            raise HttpError(404, f"not found: {path[:200]}")
        pid = self.participant(body.get("token"))
        try:
            if path == "/api/session":
                st = self.store.session(pid)
                self.on_event(
                    f"{pid}: {'resumed at' if st['next'] else 'started,'} clip {st['next'] + 1} of {st['total']}"
                    if not st["done"]
                    else f"{pid}: came back after finishing"
                )
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
        except LimitError as exc:
            raise HttpError(429, str(exc)) from None
        except AnswerError as exc:
            raise HttpError(409, str(exc)) from None
        except DamagedFileError as exc:
            raise self._damaged_file(exc) from None
        raise HttpError(404, f"not found: {path[:200]}")


class _Handler(PageHandler):
    app: StudyApp
    server_version = "facecapges-study"
    timeout = SOCKET_TIMEOUT  # socket timeout of every read: a silent client is dropped
    default_request_version = "HTTP/1.0"  # error replies to garbage still carry a status line

    request_deadline = REQUEST_DEADLINE

    def handle_one_request(self) -> None:
        """One request, whose head and body must arrive within ``request_deadline`` (the socket
        timeout bounds each read, this the whole: a client sending a byte now and then is cut)."""
        self._deadline = threading.Timer(self.request_deadline, self._cut)
        self._deadline.daemon = True
        self._deadline.start()
        self._waiting(True)
        try:
            super().handle_one_request()
        finally:
            self._deadline.cancel()

    def _waiting(self, waiting: bool) -> None:
        """Tell the server this connection waits for a request (True) or has one to answer (False)."""
        if isinstance(self.server, StudyServer):
            self.server.waiting(self.request, waiting)

    def _cut(self) -> None:
        self.close_connection = True
        try:
            self.connection.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass

    def _send(self, status: int, data: bytes, ctype: str) -> None:
        deadline = getattr(self, "_deadline", None)
        if deadline is not None:  # the request has arrived: the reply is not under the deadline
            deadline.cancel()
        self._waiting(False)
        self.send_page(status, data, ctype)

    def _json(self, status: int, doc) -> None:
        self._send(status, json.dumps(doc).encode("utf-8"), "application/json")

    def do_GET(self) -> None:
        self._waiting(False)  # its whole request is here
        url = urlsplit(self.path)
        try:
            doc, f = self.app.get(url.path, parse_qs(url.query))
            data = None if f is None else f.read_bytes()
        except HttpError as exc:
            return self._json(exc.status, {"error": str(exc)})
        except OSError:
            return self._json(404, {"error": "not found"})
        if f is None or data is None:
            return self._json(200, doc)
        self._send(200, data, content_type(f.name))

    do_HEAD = do_GET

    def _body(self) -> dict:
        """The request's JSON object, read within the bounds of the module docstring."""
        raw = self.headers.get("Content-Length")
        if raw is None:
            raise HttpError(411, "Content-Length is required")
        if not raw.strip().isdigit():
            raise HttpError(400, f"Content-Length must be a number of bytes, got {raw[:40]!r}")
        n = int(raw)
        if n > MAX_BODY:
            raise HttpError(413, f"request too large: {n} bytes (at most {MAX_BODY})")
        data = self.rfile.read(n) if n else b""
        if len(data) != n:
            raise HttpError(400, f"request body ended after {len(data)} of {n} bytes")
        self._waiting(False)  # its whole request is here
        try:
            body = json.loads(data or b"{}")
        except (ValueError, RecursionError):  # JSONDecodeError, bad UTF-8, nesting too deep
            raise HttpError(400, "request body is not JSON") from None
        if not isinstance(body, dict):
            raise HttpError(400, "request body must be a JSON object")
        return body

    def do_POST(self) -> None:
        try:
            body = self._body()
            doc = self.app.post(urlsplit(self.path).path, body)
        except HttpError as exc:
            if exc.status in (400, 411, 413):
                self.close_connection = True  # the rest of the stream cannot be trusted
            return self._json(exc.status, {"error": str(exc)})
        self._json(200, doc)


class StudyServer(ThreadingHTTPServer):
    """``ThreadingHTTPServer`` with at most :data:`MAX_CONNECTIONS` connections open at once,
    :data:`MAX_PER_ADDRESS` per client address; the longest-waiting makes room (module docs)."""

    daemon_threads = True
    max_connections = MAX_CONNECTIONS

    max_per_address = MAX_PER_ADDRESS
    request_queue_size = 128  # listen backlog: connections past it wait unaccepted (and unanswered)

    def __init__(self, *args, **kwargs):
        # open connections: socket → [client address, when it began waiting for its request (None: answering)]
        self._open: dict[socket.socket, list] = {}
        self._lock = threading.Lock()
        self.refused = 0
        self.evicted = 0
        super().__init__(*args, **kwargs)

    def waiting(self, request: socket.socket, waiting: bool) -> None:
        """The handler of ``request`` begins waiting for a request (True) or has one to answer (False)."""
        with self._lock:
            conn = self._open.get(request)
            if conn is not None:
                conn[1] = time.monotonic() if waiting else None

    def _take(self, request: socket.socket, address: str) -> bool:
        victim = None
        with self._lock:
            mine = [s for s, c in self._open.items() if c[0] == address]
            way = mine if len(mine) >= self.max_per_address else None
            if way is None and len(self._open) >= self.max_connections:
                way = list(self._open)
            if way is not None:
                idle = [s for s in way if self._open[s][1] is not None]
                if not idle:
                    return False
                victim = min(idle, key=lambda s: self._open[s][1])
                del self._open[victim]  # its slot is the newcomer's now; its thread ends on the cut
                self.evicted += 1
            self._open[request] = [address, time.monotonic()]
        if victim is not None:
            try:
                victim.shutdown(socket.SHUT_RDWR)
            except OSError:  # already closed
                pass
        return True

    def _give(self, request: socket.socket) -> None:
        with self._lock:
            self._open.pop(request, None)

    def process_request(self, request, client_address) -> None:
        address = str(client_address[0]) if client_address else "?"
        if not self._take(request, address):
            self.refused += 1
            try:
                request.settimeout(1.0)
                request.sendall(b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
            except OSError:
                pass
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._give(request)
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._give(request)

    def handle_error(self, request, client_address) -> None:  # a dropped client is no news
        pass


def make_server(
    study: Study,
    host: str = StudyServeOptions.host,
    port: int = StudyServeOptions.port,
    on_event: Callable[[str], None] | None = None,
    language: str = StudyServeOptions.language,
    timeout: float = SOCKET_TIMEOUT,
    max_connections: int = MAX_CONNECTIONS,
    max_per_address: int = MAX_PER_ADDRESS,
    request_deadline: float = REQUEST_DEADLINE,
) -> StudyServer:
    """An HTTP server for ``study`` bound to ``host:port`` (port 0: any free port); not yet serving.

    ``timeout``: seconds a connection may stay silent; ``max_connections``: served at once,
    ``max_per_address`` of them from one address; ``request_deadline``: seconds a request may take to arrive.
    """
    app = StudyApp(study, on_event, language)
    handler = type("StudyHandler", (_Handler,), {"app": app, "timeout": timeout, "request_deadline": request_deadline})
    server_cls = type(
        "BoundStudyServer",
        (StudyServer,),
        {"max_connections": int(max_connections), "max_per_address": int(max_per_address)},
    )
    return server_cls((host, port), handler)


def serve_in_thread(server: ThreadingHTTPServer) -> threading.Thread:
    """Start ``server.serve_forever`` in a daemon thread (tests, embedding)."""
    t = threading.Thread(target=server.serve_forever, daemon=True)
    t.start()
    return t


def serve_study(
    study_dir: Path,
    host: str = StudyServeOptions.host,
    port: int = StudyServeOptions.port,
    language: str = StudyServeOptions.language,
    say=echo,
) -> None:
    """The whole ``study serve`` command: check, give every participant a token, write the invitation
    links for this address, serve until Ctrl-C. ``say(text, err=False)`` gets the notes and the log."""
    from datetime import datetime

    from facecapges.errors import UserError, check_port
    from facecapges.study.build import ensure_tokens, open_study, write_invitations

    check_port(port, "--port")
    if language not in LANGUAGES:
        raise UserError(f"--language must be one of {', '.join(LANGUAGES)}, got {language!r}")
    st = open_study(study_dir)
    added = ensure_tokens(st)
    if added:
        say(
            f"note: this study had no invitation tokens; gave {added} participant(s) one. Answers given "
            "before are left out of the analysis.",
            err=True,
        )
    try:
        server = make_server(
            st, host, port, on_event=lambda m: say(f"{datetime.now():%H:%M:%S} {m}"), language=language
        )
    except OSError as exc:
        raise UserError(f"cannot listen on {host}:{port} ({exc.strerror or exc})") from None
    every = host in ("0.0.0.0", "")
    shown = "127.0.0.1" if every else host
    base = f"http://{shown if ':' not in shown else f'[{shown}]'}:{server.server_address[1]}"
    inv = write_invitations(st.dir, st.plan, base)
    say(
        f"study {study_dir}: {len(st.plan.participants)} participants "
        f"({st.plan.participants[0].id}…{st.plan.participants[-1].id}), {len(st.plan.clips)} clips"
    )
    say(
        f"serving {base}/ (Ctrl-C stops); give each participant his own link from {inv}"
        + (" (replace 127.0.0.1 by this machine's address on the network)" if every else "")
    )
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        say("stopped")
    finally:
        server.server_close()
