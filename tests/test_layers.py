"""The package's layering, as a test: a lower layer never imports a higher one.

The layers follow the data path a user's frame takes (README "Layout"):

0. conventions — ``errors``, ``rotations``, ``skeleton``, ``timing``, ``arkit``
1. ``io`` — file formats
2. ``capture`` (camera → face), ``data`` (datasets, the cache), ``features`` (audio framing)
3. ``model`` — the network and its generators; ``matching`` — the motion-matching engine beside it
4. ``training``, ``outputs``, ``avatar``
5. ``evaluation``, ``runtime``
6. ``serving``, ``study``
7. the command line: ``cli``, ``demo``, ``benchmarks`` and every area's ``commands`` module

A module may import its own layer or lower ones, never a ``commands`` module of another area (the library
does not depend on the CLI), and never a private (``_name``) of another module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "src" / "facecapges"

LAYERS: dict[str, int] = {
    "errors": 0, "rotations": 0, "skeleton": 0, "timing": 0, "arkit": 0, "constants": 0,
    "io": 1,
    "capture": 2, "data": 2, "features": 2,
    "model": 3, "matching": 3,
    "training": 4, "outputs": 4, "avatar": 4,
    "evaluation": 5, "runtime": 5,
    "serving": 6, "study": 6,
    "cli": 7, "demo": 7, "benchmarks": 7, "__init__": 7,
}
TOP = 7


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG).with_suffix("")
        yield path, ("facecapges",) + rel.parts


def _layer(parts: tuple[str, ...]) -> int:
    if parts[-1] == "commands" or parts[-1] == "__main__":
        return TOP
    area = parts[1] if len(parts) > 1 else "__init__"
    assert area in LAYERS, f"{'.'.join(parts)}: area {area!r} has no layer in tests/test_layers.py"
    return LAYERS[area]


def _imports(path: Path, parts: tuple[str, ...]):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = parts[:-1] if parts[-1] != "__init__" else parts[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("facecapges"):
                    yield node.lineno, tuple(alias.name.split(".")), []
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                mod = base + (tuple(node.module.split(".")) if node.module else ())
            elif node.module and node.module.startswith("facecapges"):
                mod = tuple(node.module.split("."))
            else:
                continue
            yield node.lineno, mod, [a.name for a in node.names]


def _violations():
    out = []
    for path, parts in _modules():
        own = _layer(parts)
        for lineno, mod, names in _imports(path, parts):
            where = f"{'/'.join(parts[1:])}.py:{lineno}"
            targets = [mod] if len(mod) > 1 else [mod + (n,) for n in names] or [mod + ("__init__",)]
            for target in targets:
                if _layer(target) > own:
                    out.append(f"{where} imports {'.'.join(target)} (layer {_layer(target)} > {own})")
            target = targets[0]
            if target[-1] == "commands" and target[:2] != parts[:2] and parts[-1] != "cli":
                if own != TOP or parts[-1] != "commands":
                    out.append(f"{where} imports another area's commands module {'.'.join(mod)}")
            for name in names:
                if name.startswith("_") and not name.startswith("__") and mod != parts[:-1]:
                    out.append(f"{where} imports the private {name} of {'.'.join(mod)}")
    return out


def test_every_area_has_a_layer():
    for _, parts in _modules():
        _layer(parts)


def test_no_upward_or_private_imports():
    bad = _violations()
    assert not bad, "imports that cut across the layers:\n" + "\n".join(bad)


@pytest.mark.parametrize("low,high", [("io", "model"), ("model", "training"), ("capture", "runtime")])
def test_the_check_sees_an_upward_import(tmp_path, low, high):
    """The checker itself must catch a planted violation (a test that cannot fail proves nothing)."""
    assert LAYERS[low] < LAYERS[high]
    src = f"from facecapges.{high} import something\n"
    tree = ast.parse(src)
    node = tree.body[0]
    assert isinstance(node, ast.ImportFrom)
    assert _layer(tuple(node.module.split("."))) > _layer(("facecapges", low, "x"))
