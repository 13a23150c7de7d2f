"""A minimal client of ``facecapges serve`` (docs/serve-protocol.md).

Streams a WAV file to the server one 15 fps frame at a time, in real time, with no face
(zero weights) and the head facing the camera, and prints each returned pose's frame
number, its round-trip time and the rotation of the right forearm. Started together with
the server, it waits for it: it retries the connection for up to ``--wait`` seconds and
reads the server's ``status`` messages ("loading") until the ``hello`` that says it is ready.
When the connection drops (the server or its cluster node died: `serve --ray`, docs/serve-cluster.md)
or no pose comes for 1 s (a hung machine), it reconnects — a server that does not answer within 1 s is
tried again — and sends ``resume`` with the last pose it got, so the avatar goes on from where it
was instead of jumping back to the rest pose; the frames of the outage are skipped.

    facecapges serve --port 8780 &
    python docs/examples/serve_client.py ws://127.0.0.1:8780 speech.wav --seconds 5

Needs only soundfile and websockets (all installed with facecapges).
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import sys
import time

import soundfile as sf
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

IDENTITY_ROT6D = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]  # first two columns of the identity matrix


async def connect_when_up(url: str, wait: float, answer: float | None):
    """Connect, retrying while the server is not listening yet (for up to ``wait`` seconds); a server
    that does not answer within ``answer`` seconds (if given) is tried again."""
    deadline = time.monotonic() + wait
    limit = answer or max(10.0, wait)
    while True:
        try:
            # close_timeout: a connection given up (no pose for 1 s) is not waited on for the server's
            # close frame, which a dead server behind a proxy never sends
            return await connect(url, max_size=2**16, open_timeout=limit, close_timeout=0.2)
        except (OSError, InvalidStatus) as exc:  # refused or no answer (TimeoutError): try again; a proxy's 5xx too
            if isinstance(exc, InvalidStatus) and exc.response.status_code < 500:
                raise SystemExit(f"{url}: {exc}") from None
            if isinstance(exc, TimeoutError):
                print(f"no answer within {limit:g} s; trying again", file=sys.stderr)
            if time.monotonic() > deadline:
                raise SystemExit(f"{url}: no server answered within {wait:g} s") from None
            await asyncio.sleep(0.1)


async def hello_of(ws, answer: float | None) -> dict:
    """The server's hello (after its status messages while it loads its style); ``answer``: seconds each may take."""
    hello = json.loads(await asyncio.wait_for(ws.recv(), timeout=answer))
    while hello["type"] == "status":  # the server is loading its style: hello follows when ready
        print(f"server: {hello['message']}", file=sys.stderr)
        hello = json.loads(await asyncio.wait_for(ws.recv(), timeout=answer))
    if hello["type"] != "hello":
        raise SystemExit(f"server said: {hello}")
    return hello


async def stream(url: str, wav: str, seconds: float, wait: float = 120.0) -> int:
    samples, sr = sf.read(wav, dtype="float32", always_2d=True)
    samples = samples.mean(axis=1)
    last_pose = None  # the last pose received: sent as `resume` after a reconnect
    k, n_frames, got = 0, None, 0
    t0 = None  # the stream's clock starts at the first hello and runs on through reconnects
    while n_frames is None or k < n_frames:
        try:
            # after a drop, a server that does not answer for 1 s is dead too (a hung machine's kernel may still
            # accept the connection): the next try may reach a live one
            answer = None if last_pose is None else 1.0
            async with await connect_when_up(url, wait, answer) as ws:
                hello = await hello_of(ws, answer)
                fps, spf = hello["fps"], hello["samples_per_frame"]
                if sr != hello["sr"]:
                    raise SystemExit(f"{wav}: {sr} Hz, the server wants {hello['sr']} Hz mono")
                forearm = hello["joints"].index("RightForeArm")
                if n_frames is None or t0 is None:
                    n_frames = min(int(seconds * fps), len(samples) * fps // sr)
                    t0 = time.monotonic()
                if last_pose is not None:  # a new stream that starts where the old one was
                    await ws.send(json.dumps({"type": "resume", "pose": last_pose}))
                    print(f"reconnected: resuming at frame {k}", file=sys.stderr)
                while k < n_frames:
                    k = max(k, int((time.monotonic() - t0) * fps))  # frames of an outage are skipped
                    # frame k owns samples floor(k·sr/fps) … floor((k+1)·sr/fps) − 1
                    a, b = k * sr // fps, (k + 1) * sr // fps
                    chunk = samples[a:b][:spf]
                    sent = time.monotonic()
                    await ws.send(json.dumps({"type": "input", "frame": k,
                                              "audio": base64.b64encode(chunk.astype("<f4").tobytes()).decode(),
                                              "face": [0.0] * len(hello["blendshapes"]), "head": IDENTITY_ROT6D}))
                    msg = json.loads(await asyncio.wait_for(ws.recv(), timeout=1.0))  # none in 1 s: dead
                    while msg["type"] == "resumed":
                        msg = json.loads(await asyncio.wait_for(ws.recv(), timeout=1.0))
                    if msg["type"] != "pose":
                        raise SystemExit(f"server said: {msg}")
                    last_pose, got = msg["pose"], got + 1
                    q = msg["pose"][4 * forearm: 4 * forearm + 4]  # (w, x, y, z)
                    print(f"frame {msg['frame']:4d}  {1000 * (time.monotonic() - sent):6.1f} ms  "
                          f"RightForeArm w={q[0]:+.3f} x={q[1]:+.3f} y={q[2]:+.3f} z={q[3]:+.3f}")
                    k += 1
                    await asyncio.sleep(max(0.0, t0 + k / fps - time.monotonic()))  # real time
        except (ConnectionClosed, TimeoutError) as exc:
            print(f"connection lost ({exc.__class__.__name__}); reconnecting", file=sys.stderr)
            await asyncio.sleep(0.05)
    return got


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("url", help="ws://HOST:PORT printed by `facecapges serve`")
    ap.add_argument("wav", help="speech, 16 kHz mono")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--wait", type=float, default=120.0, help="seconds to wait for the server to start")
    args = ap.parse_args()
    n = asyncio.run(stream(args.url, args.wav, args.seconds, args.wait))
    print(f"{n} frames")


if __name__ == "__main__":
    main()
