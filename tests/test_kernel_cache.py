"""numba's disk cache kept to the package's sources as a whole (:mod:`depthguard.kernel_cache`).

Truth: numba itself, in fresh processes — a cached kernel that inlines a function of another
module keeps the old function after that module changes (numba checks the kernel's own file
only); with :func:`keep_cache_to_sources` run first, the new one is compiled. And numba's own
choice of cache directories, under ``NUMBA_CACHE_DIR`` and beside the sources.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from depthguard.kernel_cache import STAMP, _mirrored, keep_cache_to_sources

_HELPER = """
from numba import njit

@njit(inline="always")
def value():
    return {value}
"""

_KERNEL = """
from numba import njit
from kpkg.helper import value

@njit(cache=True)
def kernel():
    return value()
"""


def _package(tmp_path: Path, value: int) -> Path:
    root = tmp_path / "kpkg"
    root.mkdir(exist_ok=True)
    (root / "__init__.py").write_text("")
    (root / "helper.py").write_text(_HELPER.format(value=value))
    if not (root / "kernel.py").exists():
        (root / "kernel.py").write_text(_KERNEL)
    return root


def _run(tmp_path: Path, keep: bool, env_extra=None) -> int:
    """``kernel()`` in a fresh process (``keep``: the package's cache kept to its sources first)."""
    code = textwrap.dedent(f"""
        from pathlib import Path
        from depthguard.kernel_cache import keep_cache_to_sources
        if {keep!r}:
            keep_cache_to_sources(Path({str(tmp_path / 'kpkg')!r}))
        from kpkg.kernel import kernel
        print(kernel())
    """)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    # no bytecode: Python's own check of a .pyc (the source's size and whole seconds) would take a
    # helper rewritten within the same second at the same size for the old one
    env.update(PYTHONPATH=os.pathsep.join([str(tmp_path), *filter(None, sys.path)]), PYTHONDONTWRITEBYTECODE="1",
               **(env_extra or {}))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return int(out.stdout.split()[-1])


@pytest.mark.parametrize("cache_dir", [False, True])
def test_a_change_of_an_inlined_module_reaches_the_cached_kernel(tmp_path, cache_dir):
    """numba alone runs the old inlined function from its cache; kept to the sources, the new one
    (beside the sources, and under ``NUMBA_CACHE_DIR``, where numba's directories are the ones
    :mod:`depthguard.kernel_cache` works out)."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")} if cache_dir else None
    root = _package(tmp_path, 1)
    assert _run(tmp_path, False, env) == 1
    if cache_dir:
        assert any(_mirrored(Path(os.path.abspath(tmp_path / "numba-cache")), root).glob("kernel.kernel-*.nbi"))
    else:
        assert any((root / "__pycache__").glob("kernel.kernel-*.nbi"))
    _package(tmp_path, 25)                              # the helper changes; kernel.py does not
    assert _run(tmp_path, False, env) == 1              # numba: the stale machine code
    assert _run(tmp_path, True, env) == 25              # kept to the sources: compiled again
    assert _run(tmp_path, True, env) == 25              # ... and then loaded from the cache


def test_unchanged_sources_keep_their_cache_and_a_touch_reads_them_once(tmp_path):
    root = _package(tmp_path, 1)
    cache = root / "__pycache__"
    cache.mkdir()
    (cache / "kernel.kernel-5.py311.nbi").write_bytes(b"i")
    (cache / "kernel.kernel-5.py311.1.nbc").write_bytes(b"c")
    (cache / "helper.cpython-311.pyc").write_bytes(b"p")
    assert keep_cache_to_sources(root) == 2                    # no stamp yet: nothing is known of them
    assert (cache / STAMP).exists() and (cache / "helper.cpython-311.pyc").exists()
    (cache / "kernel.kernel-5.py311.nbi").write_bytes(b"i")
    assert keep_cache_to_sources(root) == 0                    # the same sources
    stamp = (cache / STAMP).read_text()
    os.utime(root / "helper.py", ns=(0, 0))                    # touched, the same contents
    assert keep_cache_to_sources(root) == 0 and (cache / STAMP).read_text() != stamp
    (root / "helper.py").write_text(_HELPER.format(value=3))
    assert keep_cache_to_sources(root) == 1 and not (cache / "kernel.kernel-5.py311.nbi").exists()


def test_the_package_is_kept_where_numba_names_it():
    """numba names a kernel's cache directory after its module's file as imported (``abspath``,
    symbolic links kept): the package's own place is worked out from that path."""
    import depthguard
    from depthguard import kernel_cache

    here = Path(os.path.dirname(os.path.abspath(depthguard.__file__)))
    assert kernel_cache.PACKAGE == here
    assert kernel_cache.cache_places()[0][0] == here / "__pycache__"
