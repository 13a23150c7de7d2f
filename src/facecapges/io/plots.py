"""Matplotlib for our PNG plots, set up once: the Agg backend and a font fallback that draws CJK text.

Matplotlib's default font (DejaVu Sans) has no Chinese glyphs: without a fallback the study's Chinese
criterion names come out as empty boxes with a "Glyph … missing from font" warning each. :func:`pyplot`
puts the first installed CJK font (WenQuanYi Micro Hei — Debian's ``fonts-wqy-microhei``, which
``scripts/setup-avatar.sh`` installs — Noto Sans CJK, Source Han Sans …), found through
``matplotlib.font_manager``, after DejaVu Sans in ``font.family``; matplotlib (≥ 3.6) then takes each
glyph from the first font of that list that has it.
"""

from __future__ import annotations

import functools
from typing import Any

CJK_FILE_KEYS = ("wqy", "notosanscjk", "notosanssc", "sourcehansans")  # their files' names, lower case
CJK_FONTS = ("WenQuanYi Micro Hei", "Noto Sans CJK SC", "Noto Sans SC", "Source Han Sans SC", "Noto Sans CJK JP")


@functools.cache
def cjk_font() -> str | None:
    """The family name of an installed CJK font matplotlib can use (None when there is none)."""
    from matplotlib import font_manager

    found = _cjk_in(font_manager.fontManager)
    if found is None:  # matplotlib's font list is cached on disk from its first use: a font installed after that
        # (setup-avatar.sh's, once something imported matplotlib first) is not in it until it is added
        for path in font_manager.findSystemFonts():
            if any(key in path.lower() for key in CJK_FILE_KEYS):
                font_manager.fontManager.addfont(path)
        found = _cjk_in(font_manager.fontManager)
    return found


def _cjk_in(manager: Any) -> str | None:
    names = {f.name for f in manager.ttflist}
    for name in CJK_FONTS:
        if name in names:
            return name
    return next((n for n in sorted(names) if "CJK" in n or "WenQuanYi" in n), None)


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend, with the CJK font as the fallback of DejaVu Sans."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cjk = cjk_font()
    if cjk is not None:  # per-glyph fallback works along font.family's list (not along font.sans-serif)
        plt.rcParams["font.family"] = ["DejaVu Sans", cjk]
    return plt
