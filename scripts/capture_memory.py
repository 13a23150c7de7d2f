"""Peak memory of ``facecapges capture`` against video length (issue 28: it must be flat).

Makes an N-minute video by looping a face clip's frames (ffmpeg ``-stream_loop``, no re-encode),
runs ``capture`` on it in this process and prints the resident memory while it runs (once per
minute of video) and the peak, as JSON. Usage::

    PYTHONPATH=src nice -n 5 python scripts/capture_memory.py --minutes 1 10 30

(about 40 s of wall time per minute of 25 fps video on this 2-core machine).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path


def looped_video(src: Path, minutes: float, out: Path) -> Path:
    import cv2
    import imageio_ffmpeg

    cap = cv2.VideoCapture(str(src))
    seconds = cap.get(cv2.CAP_PROP_FRAME_COUNT) / cap.get(cv2.CAP_PROP_FPS)
    cap.release()
    loops = max(0, int(round(minutes * 60 / seconds)) - 1)
    subprocess.run(
        [
            imageio_ffmpeg.get_ffmpeg_exe(),
            "-y",
            "-loglevel",
            "error",
            "-stream_loop",
            str(loops),
            "-i",
            str(src),
            "-c",
            "copy",
            str(out),
        ],
        check=True,
    )
    return out


def measure(video: Path, out: Path) -> dict:
    """Run capture on ``video`` in a child process; its RSS by output minute and its peak."""
    r = subprocess.run([sys.executable, __file__, "--child", str(video), str(out)], capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(r.stderr[-2000:])
    return json.loads(r.stdout.strip().splitlines()[-1])


def child(video: str, out: str) -> None:
    import facecapges.capture.runner as runner
    from facecapges.benchmarks.runtime import rss_mb

    frames = [0]
    orig = runner.Records.append

    def counting(self, res):
        frames[0] += 1
        orig(self, res)

    runner.Records.append = counting  # type: ignore[method-assign]
    by_minute: dict[int, float] = {}
    stop = threading.Event()

    def watch():
        while not stop.is_set():
            by_minute[int(frames[0] / 15 / 60)] = rss_mb()
            time.sleep(1.0)

    threading.Thread(target=watch, daemon=True).start()
    t0 = time.time()
    s = runner.capture_video(video, out, force=True, progress=False)
    stop.set()
    print(
        json.dumps(
            {
                "frames": s["frames"],
                "minutes": round(s["frames"] / 15 / 60, 2),
                "rss_mb_by_minute": {k: round(v, 1) for k, v in sorted(by_minute.items())},
                "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
                "wall_s": round(time.time() - t0, 1),
            }
        )
    )


def main() -> None:
    if sys.argv[1:2] == ["--child"]:
        return child(sys.argv[2], sys.argv[3])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[1, 10, 30])
    ap.add_argument("--clip", type=Path, default=Path("../shared/data/face/WDA_KatieHill_000.mp4"))
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="capture-memory-") as tmp:
        for m in a.minutes:
            v = looped_video(a.clip, m, Path(tmp) / f"loop{m:g}.mp4")
            print(json.dumps({"video_minutes": m, **measure(v, Path(tmp) / "face.json")}), flush=True)
            v.unlink()


if __name__ == "__main__":
    main()
