"""The package's layering, as a test: a lower layer never imports a higher one.

The layers follow the data path a user's frame takes (README "Layout"):

0. conventions — ``errors``, ``rotations`` (``rotations_compiled``: its Numba form), ``skeleton``, ``timing``,
   ``arkit``, ``progress``
1. ``io`` — file formats
2. ``capture`` (camera → face), ``data`` (datasets, the cache)
3. ``engine`` — the contract both engines meet: style and stream interfaces, the batched protocol,
   the inputs plan and the one generation loop, slots, intensity, the style file
4. ``network`` — the thesis network and its file format
5. ``matching`` — the motion-matching engine (its speech predictor uses the network's encoders)
6. ``styles`` — the shelf above both engines: list, resolve, install, load any engine's style
7. ``training``, ``avatar``
8. ``evaluation``, ``runtime``
9. ``serving``, ``study``
10. ``commands`` (the command line: ``cli`` and one module per command group, with ``__main__`` for
   ``python -m facecapges``), ``benchmarks`` (the ``bench`` runner and one module per area), and the
   package's ``__init__`` (the Python API, imported lazily)

A module may import its own layer or lower ones, never a private (``_name``) of another module, and only
``commands`` and ``__main__`` may import ``commands`` (the library does not depend on the CLI).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "src" / "facecapges"

LAYERS: dict[str, int] = {
    "errors": 0, "rotations": 0, "rotations_compiled": 0, "skeleton": 0, "timing": 0, "arkit": 0, "progress": 0,
    "io": 1,
    "capture": 2, "data": 2,
    "engine": 3,
    "network": 4,
    "matching": 5,
    "styles": 6,
    "training": 7, "avatar": 7,
    "evaluation": 8, "runtime": 8,
    "serving": 9, "study": 9,
    "commands": 10, "benchmarks": 10, "__main__": 10, "__init__": 10,
}
TOP = 10


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG).with_suffix("")
        yield path, ("facecapges",) + rel.parts


def _layer(parts: tuple[str, ...]) -> int:
    area = parts[1] if len(parts) > 1 else "__init__"
    assert area in LAYERS, f"{'.'.join(parts)}: area {area!r} has no layer in tests/test_layers.py"
    return LAYERS[area]


def _imports(source: str, parts: tuple[str, ...]):
    tree = ast.parse(source)
    package = parts[:-1]
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


def _module_violations(source: str, parts: tuple[str, ...]) -> list[str]:
    """What module ``parts`` (its text ``source``) imports across the layers."""
    out = []
    own = _layer(parts)
    for lineno, mod, names in _imports(source, parts):
        where = f"{'/'.join(parts[1:])}.py:{lineno}"
        targets = [mod] if len(mod) > 1 else [mod + (n,) for n in names] or [mod + ("__init__",)]
        for target in targets:
            if _layer(target) > own:
                out.append(f"{where} imports {'.'.join(target)} (layer {_layer(target)} > {own})")
            if target[1] == "commands" and parts[1] not in ("commands", "__main__"):
                out.append(f"{where} imports the command line {'.'.join(target)} (the library never does)")
        for name in names:
            if name.startswith("_") and not name.startswith("__") and mod != parts[:-1]:
                out.append(f"{where} imports the private {name} of {'.'.join(mod)}")
    return out


def _violations():
    out = []
    for path, parts in _modules():
        out += _module_violations(path.read_text(encoding="utf-8"), parts)
    return out


def test_every_area_has_a_layer():
    for _, parts in _modules():
        _layer(parts)


def test_no_upward_or_private_imports():
    bad = _violations()
    assert not bad, "imports that cut across the layers:\n" + "\n".join(bad)


@pytest.mark.parametrize(
    "module,source",
    [
        ("io.bvh", "from facecapges.network import network\n"),
        ("network.network", "import facecapges.training.train\n"),
        ("engine.contract", "from facecapges.network.style import NetworkStyle\n"),
        ("network.style", "from facecapges.matching.style import MatchingStyle\n"),
        ("matching.build", "from facecapges.styles import check_style_name\n"),
        ("matching.engine", "import facecapges.styles\n"),
        ("capture.pipeline", "from facecapges.runtime.session import Session\n"),
        ("data.prepare", "from facecapges.styles import load_style\n"),
        ("serving.server", "from facecapges.commands.cli import app\n"),
        ("benchmarks.model", "from facecapges.commands.styles import register\n"),
        ("__init__", "from facecapges.commands import cli\n"),
        ("runtime.live", "from facecapges.skeleton import _private\n"),
    ],
)
def test_the_check_sees_a_planted_violation(module, source):
    """The checker itself must catch a planted violation (a test that cannot fail proves nothing)."""
    parts = ("facecapges",) + tuple(module.split("."))
    assert _module_violations(source, parts), f"{module}: {source!r} was not caught"


def test_the_command_line_may_import_the_library():
    for source in ("from facecapges.serving.server import serve\n", "from facecapges.commands.cli import main\n"):
        assert not _module_violations(source, ("facecapges", "commands", "serving"))
    assert not _module_violations("from facecapges.commands.cli import main\n", ("facecapges", "__main__"))
