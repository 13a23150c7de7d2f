"""Benchmark of the user-study tool on the real shared BEAT clip.

Figures: time to plan a large study; ``study create`` time and pose-file size for K = 3
versions of a clip (the clip, a time-shifted copy and the reversed motion of
the shared ``data/beat/2_scott_0_1_1``; 5 s quick, 30 s full); and in headless Chromium
(software WebGL) the page's start-up, trial loading time and playback: the share of
the clip's frames actually drawn while the three avatars play in one scene
(1.0 = every frame at the clip's 15 fps).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from facecapges.benchmarks.render import shared_file
from facecapges.timing import AUDIO_SR


def run(quick: bool, shared: Path) -> dict:
    import numpy as np
    import yaml

    from facecapges.study.design import make_plan

    out: dict = {}
    t = time.perf_counter()
    make_plan([f"c{i}" for i in range(40)], [f"s{i}" for i in range(5)], 100, seed=0)
    out["plan_100_participants_40_clips_5_systems_ms"] = round(1000 * (time.perf_counter() - t), 2)

    bvh_path = shared_file(shared, "data/beat/2_scott_0_1_1.bvh")
    wav_path = shared_file(shared, "data/beat/2_scott_0_1_1.wav")
    if bvh_path is None or wav_path is None:
        from facecapges.errors import UserError

        raise UserError(f"{shared}: the study benchmark needs data/beat/2_scott_0_1_1.bvh and .wav")
    from facecapges.avatar.render.browser import Browser
    from facecapges.io.audio import load_audio, save_audio
    from facecapges.io.bvh import read_bvh, write_bvh
    from facecapges.study.build import create_study, open_study
    from facecapges.study.server import make_server, serve_in_thread

    seconds = 5 if quick else 30
    with tempfile.TemporaryDirectory(prefix="facecapges-study-bench-") as tmp:
        tmp = Path(tmp)
        b = read_bvh(bvh_path)
        n = int(seconds * b.fps)
        m = b.motion[:n]
        # the shifted copy starts 150 frames later and wraps around: as long as the clip
        systems = {"clip": m, "shifted": np.roll(b.motion, -150, axis=0)[:n], "reversed": m[::-1]}
        for s, mo in systems.items():
            write_bvh(tmp / f"{s}.bvh", b.skeleton, mo, b.fps)
        save_audio(tmp / "a.wav", load_audio(wav_path)[: int(seconds * AUDIO_SR)])
        (tmp / "CLIPS.yaml").write_text(
            yaml.safe_dump({"clips": [{"id": "c", "audio": "a.wav", "bvh": {s: f"{s}.bvh" for s in systems}}]})
        )
        t = time.perf_counter()
        create_study(tmp / "CLIPS.yaml", tmp / "study", 1, progress=False)
        out["create_s"] = round(time.perf_counter() - t, 2)
        size = sum(f.stat().st_size for f in (tmp / "study" / "media" / "c").glob("motion-*.json"))
        out["pose_json_mb_per_version_minute"] = round(size / 3 / 1e6 * 60 / seconds, 2)

        st = open_study(tmp / "study")
        token = st.plan.participants[0].token  # the invitation link is the only credential
        server = make_server(st, "127.0.0.1", 0)
        serve_in_thread(server)
        try:
            with Browser({"/blank.json": b"{}"}, "/blank.json", 1200, 1000, timeout=90) as br:

                def js(expr: str):
                    r = br.call(
                        "Runtime.evaluate", expression=expr, awaitPromise=True, returnByValue=True, userGesture=True
                    )
                    return r.get("result", {}).get("value")

                def wait(expr: str, limit: float = 60.0) -> float:
                    t0 = time.perf_counter()
                    while not js(f"(() => {{ try {{ return {expr}; }} catch (e) {{ return false; }} }})()"):
                        if time.perf_counter() - t0 > limit:
                            raise RuntimeError(f"study page never reached {expr}")
                        time.sleep(0.02)
                    return time.perf_counter() - t0

                br.call("Page.navigate", url=f"http://127.0.0.1:{server.server_address[1]}/?invite={token}")
                out["page_start_s"] = round(wait("window.study.screen === 'welcome'"), 2)
                js("document.getElementById('start').click()")
                out["trial_load_s"] = round(wait("window.study.ready"), 2)
                js("document.getElementById('play').click()")
                wait("window.study.playing")
                d0 = js("window.study.draws")
                t0 = time.perf_counter()
                time.sleep(1.0 if quick else 5.0)
                drawn = js("window.study.draws") - d0
                elapsed = time.perf_counter() - t0
                fps = float(open_study(tmp / "study").doc["fps"])
                out["playback_drawn_fps"] = round(drawn / elapsed, 1)
                out["playback_frames_drawn_share"] = round(min(1.0, drawn / (elapsed * fps)), 3)
                out["audio_clock"] = bool(js("window.study.audioClock"))
        finally:
            server.shutdown()
            server.server_close()
    out["clip_seconds"] = seconds
    out["versions"] = 3
    return out


if __name__ == "__main__":
    import json

    print(json.dumps(run(quick=True, shared=Path("../shared")), indent=1))
