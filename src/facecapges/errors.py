"""The one exception type a user sees.

Anything the user can fix (a missing file, a malformed BVH, a wrong skeleton, an
existing output) is raised as :class:`UserError`. The command line catches it,
prints its message on one line and exits with status 2 — never a traceback.

The error policy, one rule per kind of failure:

* **UserError** — input a person gave us (files, command-line values, a skeleton, an
  output location) that is wrong; the message names the thing and says what to do.
  The same condition raises it wherever it is found (e.g. a skeleton without the BEAT
  joints, in the avatar and in the VMC sender alike).
* **ValueError** (and ``TypeError``) — a programming error: a function called with
  arrays of the wrong shape by our own code. Never caught; a test fails.
* **Protocol errors of servers** — :class:`facecapges.runtime.outputs.protocol.ProtocolError`,
  ``runtime.inputs.livelink.PacketError``, ``study.store.AnswerError``: bad messages from a
  client over the network. They are answered (an ``error`` message, an HTTP status)
  or counted and dropped, and logged at most once per connection; they never stop a
  server and never reach the user as a traceback.
* Process-wide state a function changes (torch's thread count) is restored by it or by
  the object that owns it (``Session.close``).

Messages that are not errors: a library function that talks to the user while it works
takes ``say(text, err=False)`` (a line on stdout, or stderr) and ``warn(text)`` (a
warning or note on stderr); :func:`echo` and :func:`echo_warning` (yellow on a terminal)
are the defaults, and every command warns with :func:`echo_warning`.
"""

from __future__ import annotations

import sys
from pathlib import Path


class UserError(Exception):
    """A problem with the user's input, described in words the user can act on."""


def echo(text: str, err: bool = False) -> None:
    """The default ``say``: a line on stdout (stderr with ``err``)."""
    print(text, file=sys.stderr if err else sys.stdout, flush=True)


def echo_warning(text: str) -> None:
    """The one ``warn``: a line on stderr, in yellow when stderr is a terminal (plain text otherwise)."""
    if sys.stderr.isatty():
        from rich.console import Console

        Console(stderr=True, soft_wrap=True, markup=False, highlight=False, emoji=False).print(text, style="yellow")
    else:
        print(text, file=sys.stderr, flush=True)


def file_error(path: str | Path, problem: str) -> UserError:
    """A :class:`UserError` that names the file first: ``"<path>: <problem>"``."""
    return UserError(f"{path}: {problem}")


def require_file(path: str | Path, what: str = "file") -> Path:
    """Return ``path`` as a Path, or raise a UserError if it is not an existing file."""
    p = Path(path)
    if not p.exists():
        raise file_error(p, f"{what} not found")
    if not p.is_file():
        raise file_error(p, f"{what} is not a regular file")
    return p


def refuse_overwrite(path: str | Path, force: bool, flag: str = "--force") -> Path:
    """Raise unless ``path`` is free or ``force`` is set (nothing is lost without asking)."""
    p = Path(path)
    if p.exists() and not force:
        raise file_error(p, f"already exists; pass {flag} to overwrite it")
    return p


def _writable_folder(folder: Path) -> None:
    """Raise unless files can be created in ``folder`` or in the nearest folder above it that exists."""
    import errno
    import os
    import tempfile

    anc = folder
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise file_error(anc, "is a file, not a folder; choose another output location")
    try:
        with tempfile.TemporaryFile(dir=anc):
            pass
    except OSError as exc:
        why = "the file system is read-only" if exc.errno == errno.EROFS else (exc.strerror or str(exc)).lower()
        raise file_error(anc, f"cannot write here ({why})") from None
    if not os.access(anc, os.W_OK | os.X_OK):
        raise file_error(anc, "cannot write here (permission denied)")


def check_output_file(path: str | Path, force: bool = False, flag: str = "--force") -> Path:
    """Check, before any work, that ``path`` can be written as a file and is not kept.

    One rule for every command that writes: an output that exists is kept unless
    ``force``; a path naming a folder, a parent that is a file or a folder that cannot
    be written (read-only file system, no permission) is a :class:`UserError` now
    rather than a traceback after the work.
    """
    p = Path(path)
    if p.is_dir():
        raise file_error(p, "is a folder; the output must name a file")
    refuse_overwrite(p, force, flag)
    _writable_folder(p.parent)
    return p


def check_output_dir(
    folder: str | Path, names: list[str] | tuple[str, ...] = (), force: bool = False, flag: str = "--force"
) -> Path:
    """Check, before any work, that ``folder`` can receive the outputs ``names`` (kept unless ``force``).

    Every name is checked, not only the first, so nothing in the folder is overwritten
    without ``force``.
    """
    d = Path(folder)
    if d.exists() and not d.is_dir():
        raise file_error(d, "is a file; the output must name a folder")
    existing = [n for n in names if (d / n).exists()]
    if existing and not force:
        also = ", ".join(existing[1:4]) + (", …" if len(existing) > 4 else "")
        raise file_error(
            d / existing[0], "already exists" + (f" (so do {also})" if also else "") + f"; pass {flag} to overwrite"
        )
    _writable_folder(d)
    return d


def check_port(port: int, flag: str = "--port") -> int:
    """A TCP port number 0–65535 (0: any free port), else a UserError naming ``flag``."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise UserError(f"{flag}: port {port} is out of range (0-65535)")
    return port


def check_port_free(host: str, port: int, flag: str = "--port", udp: bool = False) -> None:
    """Raise now, before any model loads, if a server could not listen on ``host:port`` (in use, or an address
    this machine does not have). Port 0 (any free port) always passes. The probe binds as our servers do
    (``SO_REUSEADDR``) and closes at once."""
    import socket

    check_port(port, flag)
    if port == 0:
        return
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM if udp else socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise UserError(f"{flag} {host}:{port}: unknown host ({exc.strerror})") from None
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as exc:
            import errno

            if exc.errno == errno.EADDRINUSE:
                why = f"port {port} is in use (another program, or another facecapges, listens there)"
                raise UserError(f"{flag} {host}:{port}: {why}; choose another port, or 0 for any free one") from None
            raise UserError(
                f"{flag} {host}:{port}: cannot listen there ({(exc.strerror or str(exc)).lower()})"
            ) from None
