"""numba's disk cache kept to the package's sources as a whole (R29).

numba checks a cached kernel against its **own** source file only (its modification time and
size). A kernel that inlines a function of another module — ``inline="always"``, an
``@overload``, a ``carray`` view of another camera's arrays — keeps its cached machine code
when that other module changes, and runs with the old one: when an experiment of issue 29 made
:mod:`~depthguard.fusion.camera_views` read float32, a grid kernel cached before it read the
float32 arrays as float64 and crashed the process — and it could as well have answered wrong
distances without a crash.

:func:`keep_cache_to_sources` therefore keeps, beside each place numba may cache the package's
kernels (next to the sources, under ``NUMBA_CACHE_DIR``, or in the user's cache directory), a
digest of all the package's sources; where it differs from the sources', every cached kernel of
the package there is deleted before any is loaded (numba compiles them again: ``depthguard
warm-up``). ``import depthguard`` calls it once per process (3 ms with the sources unchanged).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["sources_digest", "cache_places", "keep_cache_to_sources", "STAMP"]

#: the digest file's name in each place
STAMP = "depthguard-sources.sha256"

#: the package's directory as numba sees it (``os.path.abspath`` of the modules' files, symbolic
#: links kept: numba names its cache directories after that path, not the resolved one)
PACKAGE = Path(os.path.abspath(os.path.dirname(__file__)))


def _sources(root: Path) -> list[Path]:
    """The ``.py`` files under ``root``, sorted (``__pycache__`` left out)."""
    out = []
    for d, subdirs, files in os.walk(root):
        subdirs[:] = [s for s in subdirs if s != "__pycache__"]
        out += [Path(d) / f for f in files if f.endswith(".py")]
    return sorted(out)


def _stat_key(files: list[Path]) -> str:
    """A digest of the files' paths, sizes and modification times: unchanged files give the
    same key without reading them."""
    h = hashlib.sha256()
    for p in files:
        st = p.stat()
        h.update(f"{p}\0{st.st_size}\0{st.st_mtime_ns}\0".encode())
    return h.hexdigest()


def sources_digest(root: Path = PACKAGE, files: list[Path] | None = None) -> str:
    """SHA-256 of every ``.py`` file under ``root`` (relative path and contents, in order)."""
    h = hashlib.sha256()
    for p in (_sources(root) if files is None else files):
        h.update(p.relative_to(root).as_posix().encode())
        h.update(b"\0")
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def _source_dirs(files: list[Path]) -> list[Path]:
    return sorted({p.parent for p in files})


def _mirrored(base: Path, d: Path) -> Path:
    """Where numba's user-provided and user-wide locators cache the kernels of directory ``d``
    under ``base`` (numba's ``get_suitable_cache_subpath``: the directory's name and the SHA-1
    of its absolute path)."""
    return base / f"{d.name}_{hashlib.sha1(str(d).encode()).hexdigest()}"


def _user_cache_dir() -> Path:
    """numba's user-wide cache directory (its ``appdirs`` ``user_cache_dir("numba")``), without
    importing numba: ``$XDG_CACHE_HOME/numba`` or ``~/.cache/numba``; ``~/Library/Caches/numba``
    on macOS."""
    import sys

    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "numba"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "numba"


def cache_places(root: Path = PACKAGE, files: list[Path] | None = None) -> list[tuple[Path, list[Path]]]:
    """``(stamp directory, cache directories)`` of each place numba may cache ``root``'s kernels:
    the ``__pycache__`` beside the sources; with ``NUMBA_CACHE_DIR`` its mirror of them; the
    user's numba cache directory (where the sources are not writable)."""
    dirs = _source_dirs(_sources(root) if files is None else files)
    places = [(root / "__pycache__", [d / "__pycache__" for d in dirs])]
    bases = []
    if os.environ.get("NUMBA_CACHE_DIR"):
        bases.append(Path(os.path.abspath(os.environ["NUMBA_CACHE_DIR"])))     # (numba: abspath, too)
    try:
        bases.append(_user_cache_dir())
    except (RuntimeError, KeyError):           # (no home directory: that place is not kept)
        pass
    for base in bases:
        places.append((_mirrored(base, root), [_mirrored(base, d) for d in dirs]))
    return places


def keep_cache_to_sources(root: Path = PACKAGE) -> int:
    """Delete the package's cached kernels wherever their place's digest is not the sources'
    (module docstring); returns the number of files deleted. A place with no cached kernel only
    gets the digest; one that cannot be written is left as it is. The stamp holds the sources'
    digest and a key of their sizes and times, so that unchanged sources are not read again."""
    files = _sources(root)
    key = _stat_key(files)
    digest = None
    removed = 0
    for stamp_dir, cache_dirs in cache_places(root, files):
        if not stamp_dir.parent.is_dir():
            continue                                   # nothing cached in that place
        stamp = stamp_dir / STAMP
        try:
            held = stamp.read_text().split()
        except OSError:
            held = []
        if len(held) == 2 and held[1] == key:
            continue                                   # the same files, untouched
        digest = sources_digest(root, files) if digest is None else digest
        try:
            if not (len(held) == 2 and held[0] == digest):     # (the same contents: only the key is new)
                for d in cache_dirs:
                    if d.is_dir():
                        for f in d.iterdir():
                            if f.suffix in (".nbi", ".nbc"):
                                f.unlink(missing_ok=True)
                                removed += 1
            stamp_dir.mkdir(exist_ok=True)     # (numba makes the directories it caches in as it needs them)
            tmp = stamp.with_name(f"{STAMP}.{os.getpid()}")
            tmp.write_text(f"{digest}\n{key}\n")
            os.replace(tmp, stamp)
        except OSError:
            continue
    return removed
