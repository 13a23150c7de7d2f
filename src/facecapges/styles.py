"""The style shelf: list, resolve, install and load the styles of every engine.

A style is one ``.safetensors`` file (:mod:`facecapges.engine.files`) of an engine: the thesis
network's (:mod:`facecapges.network.style`) or motion matching's (:mod:`facecapges.matching.style`);
:func:`load_style` reads the file, picks the engine from its ``format`` and returns a
:class:`~facecapges.engine.contract.GestureEngine`, what every caller uses.

Styles ship in ``facecapges/assets/styles/<name>.safetensors`` with a model card
``<name>.md``; ``DEFAULT_STYLE`` is the motion-matching style of the shared BEAT speaker
(``DEFAULT_NETWORK_STYLE`` the thesis network trained on the same speaker). Styles a
user trains are installed (``facecapges styles install RUN``) into the user data
folder :func:`user_styles_dir` — ``$FACECAPGES_STYLES`` if set, else
``$XDG_DATA_HOME/facecapges/styles`` (``~/.local/share/facecapges/styles`` by
default) — and found by ``--style NAME`` like the shipped ones; a user style of the
same name as a shipped one takes precedence. Matching styles are built here too
(:func:`build_matching_style`: the destination and the name are the shelf's, the building
:mod:`facecapges.matching.build`'s).
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import resources
from pathlib import Path

from facecapges.engine.contract import GestureEngine
from facecapges.engine.files import check_meta, read_file
from facecapges.errors import UserError, file_error
from facecapges.network.style import NetworkStyle
from facecapges.skeleton import Skeleton

DEFAULT_STYLE = "beat2-scott-mm"  # motion matching: measured best on validation (its model card)


DEFAULT_NETWORK_STYLE = "beat2-scott-demo"  # the thesis network of the same speaker (train / ablate / its bench)


def styles_dir() -> Path:
    """The styles shipped inside the package."""
    return Path(str(resources.files("facecapges") / "assets" / "styles"))


def user_styles_dir() -> Path:
    """Where ``styles install`` puts the user's own styles (module docs)."""
    import os

    if os.environ.get("FACECAPGES_STYLES"):
        return Path(os.environ["FACECAPGES_STYLES"])
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "facecapges" / "styles"


def list_styles() -> dict[str, Path]:
    """Every style by name: the shipped ones, then the user's (which win on a name clash)."""
    out: dict[str, Path] = {}
    for d in (styles_dir(), user_styles_dir()):
        if d.is_dir():
            out.update({p.stem: p for p in sorted(d.glob("*.safetensors"))})
    return out


MAX_NAME_CHARS = 64  # a style's name: its files (NAME.safetensors, NAME.log.csv, .install-NAME-…) stay short


def check_style_name(name: str | None) -> str:
    """``name`` if it can name a style (letters, digits, '.', '_', '-'; at most :data:`MAX_NAME_CHARS`)."""
    import re

    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name or ""):
        raise UserError(f"style name {name!r}: use letters, digits, '.', '_' and '-' only")
    assert name is not None
    if len(name) > MAX_NAME_CHARS:
        raise UserError(f"style name {name[:20]}…: {len(name)} characters; a style name has at most {MAX_NAME_CHARS}")
    return name


MAX_INSTALL_BYTES = {"checkpoint": 1 << 30, "log": 64 << 20, "card": 1 << 20, "fgd": 256 << 20}


MAX_INSTALL_FILES = 256  # files of a model.fgd/ folder


def _install_parts(src: Path, name: str) -> list[tuple[Path, str, str]]:
    """What :func:`install_style` copies beside the checkpoint: (source, name in the store, kind)."""
    folder = src.parent
    parts = [(src, f"{name}.safetensors", "checkpoint")]
    parts += [
        (f, n, k)
        for f, n, k in (
            (folder / "log.csv", f"{name}.log.csv", "log"),
            (folder / "model_card.md", f"{name}.md", "card"),
        )
        if f.is_symlink() or f.exists()
    ]
    card = src.with_suffix(".md")  # a style file's card beside it (`styles build --out`)
    if not (folder / "model_card.md").exists() and (card.is_symlink() or card.exists()):
        parts.append((card, f"{name}.md", "card"))
    return parts


def install_style(run: str | Path, name: str | None = None, force: bool = False) -> Path:
    """Copy a trained model (a run folder or a ``.safetensors`` file) into :func:`user_styles_dir`.

    The file is checked first (it must load as a streaming checkpoint). Beside it go
    the run's ``log.csv`` (as ``NAME.log.csv``), a model card ``NAME.md`` if the run has
    one (``model_card.md``) and its FGD autoencoder folder if ``fgd-train`` wrote one
    (``model.fgd/`` → ``NAME.fgd/``). An existing user style of that name is replaced
    only with ``force``.

    What is copied comes from outside: a symbolic link anywhere in it (the checkpoint, the
    log, the card, inside ``model.fgd/``) is refused, each file's size is capped
    (:data:`MAX_INSTALL_BYTES`, checked while copying too), and everything is first copied
    into a temporary folder of the styles store and moved into place only when all of it
    was copied — a refused or failed install leaves the store as it was.
    """
    import shutil
    import tempfile

    src = resolve(run)
    folder = src.parent
    name = name or (folder.name if src.name == "model.safetensors" else src.stem)
    check_style_name(name)
    _no_link(src)
    load_style(src)  # refuse what would not load
    dest_dir = user_styles_dir()
    dest = dest_dir / f"{name}.safetensors"
    if dest.exists() and not force:
        raise UserError(f"{dest}: a style named {name!r} is installed; pass --force to replace it")
    dest_dir.mkdir(parents=True, exist_ok=True)
    parts = _install_parts(src, name)
    fgd = src.with_suffix(".fgd")
    has_fgd = fgd.is_symlink() or fgd.exists()
    for n, is_dir in [(n, False) for _, n, _ in parts] + ([(f"{name}.fgd", True)] if has_fgd else []):
        _check_destination(dest_dir / n, is_dir, force)
    stage = Path(tempfile.mkdtemp(prefix=f".install-{name}-", dir=dest_dir))
    try:
        for f, n, kind in parts:
            _copy_regular(f, stage / n, MAX_INSTALL_BYTES[kind])
        if has_fgd:
            _copy_tree(fgd, stage / f"{name}.fgd")
        for f in sorted(stage.iterdir(), key=lambda p: p.suffix == ".safetensors"):  # the checkpoint last
            target = dest_dir / f.name
            if target.is_symlink() or (target.exists() and not target.is_dir()):
                target.unlink()  # a link itself, never what it points to (allowed by _check_destination)
            elif target.is_dir():
                shutil.rmtree(target)
            f.replace(target)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return dest


def _check_destination(target: Path, is_dir: bool, force: bool) -> None:
    """Refuse (without ``force``) a destination in the styles store that is a symbolic link or of the other
    kind (a file where a folder goes, or a folder where a file goes): install replaces only what it wrote."""
    if force or not (target.is_symlink() or target.exists()):
        return
    if target.is_symlink():
        raise file_error(
            target, "is a symbolic link in the styles folder; pass --force to replace the link (not what it points to)"
        )
    if target.is_dir() != is_dir:
        kind = "a folder" if target.is_dir() else "a file"
        raise file_error(
            target,
            f"is {kind} in the styles folder where the style's {'folder' if is_dir else 'file'} "
            "goes; pass --force to replace it",
        )


def _no_link(p: Path) -> None:
    if p.is_symlink():
        raise file_error(p, "is a symbolic link; styles install copies only the run's own files (copy it in)")


def _copy_regular(src: Path, dst: Path, cap: int) -> int:
    """Copy one regular file (never through a link), at most ``cap`` bytes; returns its size."""
    import os
    import stat

    _no_link(src)
    if not stat.S_ISREG(src.lstat().st_mode):  # a FIFO would block the open, a device never end
        raise file_error(src, "is not a regular file")
    try:  # no link, no blocking, even if it was swapped since the check
        fd = os.open(src, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise file_error(src, f"cannot be read ({exc.strerror or exc})") from None
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise file_error(src, "is not a regular file")
        if st.st_size > cap:
            raise file_error(src, f"is {st.st_size / 2**20:.1f} MB, more than a style's file may be ({cap >> 20} MB)")
        n = 0
        with open(dst, "wb") as out:
            while chunk := f.read(1 << 20):
                n += len(chunk)
                if n > cap:  # it grew while we read
                    raise file_error(src, f"is more than {cap >> 20} MB")
                out.write(chunk)
    return n


def _copy_tree(src: Path, dst: Path) -> None:
    """Copy a folder of regular files and folders (no links, at most MAX_INSTALL_FILES files, capped in size)."""
    import os

    _no_link(src)
    if not src.is_dir():
        raise file_error(src, "is not a folder")
    budget, files = MAX_INSTALL_BYTES["fgd"], 0
    for root, dirs, names in os.walk(src, followlinks=False):
        r = Path(root)
        (dst / r.relative_to(src)).mkdir(parents=True, exist_ok=True)
        for d in dirs:
            _no_link(r / d)
        for n in names:
            files += 1
            if files > MAX_INSTALL_FILES:
                raise file_error(src, f"holds more than {MAX_INSTALL_FILES} files")
            budget -= _copy_regular(r / n, dst / r.relative_to(src) / n, budget)


def resolve(checkpoint: str | Path | None = None, style: str | None = None) -> Path:
    """Path of a checkpoint given a file, a style name, or neither (the default style)."""
    if checkpoint is not None and style is not None:
        raise UserError("give either --checkpoint or --style, not both")
    if checkpoint is not None:
        p = Path(checkpoint)
        if p.is_dir():
            p = p / "model.safetensors"
        if not p.is_file():
            raise file_error(p, "checkpoint not found")
        return p
    name = style or DEFAULT_STYLE
    styles = list_styles()
    if name not in styles:
        known = ", ".join(styles) or "none installed"
        raise UserError(
            f"unknown style {name!r} (installed: {known}; install your own with `facecapges styles install RUN`)"
        )
    return styles[name]


def load_style(path: str | Path | None = None, style: str | None = None) -> GestureEngine:
    """Load a checkpoint file or installed style; clear errors for corrupt/foreign files.

    A network style gives a :class:`NetworkStyle`, a motion-matching style (format
    ``facecapges-matching-1``) a :class:`facecapges.matching.style.MatchingStyle`: both are
    :class:`~facecapges.engine.contract.GestureEngine` s, what every caller uses.
    """
    from facecapges.matching import style as matching_style
    from facecapges.network import style as network_style

    p = resolve(path, style)
    tensors, meta = read_file(p, numpy_formats=(matching_style.FORMAT,))  # matching: NumPy, no torch
    if meta is None:
        raise file_error(p, "not a FaceCapGes checkpoint (no 'facecapges' metadata)")
    if isinstance(meta, dict) and meta.get("format") == matching_style.FORMAT:
        check_meta(p, meta)
        return matching_style.from_file(p, tensors, meta)
    return network_style.from_file(p, tensors, meta)


def network_only(ckpt: GestureEngine, what: str) -> NetworkStyle:
    """``ckpt`` if it is a network style; a clear error for another engine's style where only a network fits."""
    if not isinstance(ckpt, NetworkStyle):
        raise UserError(f"{ckpt.path}: a {ckpt.label} style; {what} needs a network style (FaceCapGes)")
    return ckpt


def load_style_or_file(spec: str | Path) -> GestureEngine:
    """A checkpoint named by a path (an existing file or run folder, or anything that looks like a
    path: a suffix or a folder in it) or else by an installed style's name."""
    p = Path(spec)
    looks_like_path = p.exists() or bool(p.suffix) or len(p.parts) > 1
    return load_style(p) if looks_like_path else load_style(style=str(spec))


def load_skeleton(checkpoint_path: str | Path | None = None) -> Skeleton:
    """The BEAT skeleton stored with a checkpoint (default: the default style's)."""
    return load_style(checkpoint_path).skeleton


def build_matching_style(
    name: str,
    pairs: list[tuple[Path, Path]],
    out: Path | None = None,
    force: bool = False,
    say: Callable[[str], None] = print,
    **settings,
) -> Path:
    """``styles build``: a matching style from paired takes (:func:`facecapges.matching.build.build_style`),
    written to ``out`` or installed into :func:`user_styles_dir` under ``name``; its path."""
    from facecapges.matching.build import build_style

    check_style_name(name)
    dest = Path(out) if out is not None else user_styles_dir() / f"{name}.safetensors"
    return build_style(name, pairs, dest, load_skeleton, force=force, say=say, **settings)
