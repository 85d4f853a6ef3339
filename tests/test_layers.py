"""No import runs back up the layers (issue 28; docs/ARCHITECTURE.md, "Import graph").

Truth: the source text of every module of ``src/depthguard``, parsed with ``ast`` —
imports at module level and inside functions (lazy imports count) — and the order
declared once in :data:`depthguard.layers.LAYERS`. The walker itself is checked on
hand-written snippets whose imports are known.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import depthguard
from depthguard.layers import LAYERS

PACKAGE = Path(depthguard.__file__).parent

#: (importer module, imported module) allowed to run back up, each explained in
#: docs/ARCHITECTURE.md ("Import graph"); at most two
ALLOWED: dict[tuple[str, str], str] = {}


def _module_name(path: Path) -> tuple[str, bool]:
    """Dotted name of the module at ``path`` and whether it is a package's ``__init__``."""
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    is_init = parts[-1] == "__init__"
    if is_init:
        parts = parts[:-1]
    return ".".join(parts), is_init


def imported_modules(source: str, module: str, is_init: bool = False) -> list[tuple[str, int]]:
    """Every ``depthguard`` module that ``source`` (the text of ``module``) imports, anywhere in
    it, as ``(dotted name, line)``; ``from depthguard import x`` names ``depthguard.x``."""
    found = []
    package = module.split(".") if is_init else module.split(".")[:-1]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            # `from depthguard.x import y` imports y of x, or the module x.y: either way room x,
            # except at the root, where y is the room
            if target == "depthguard" or (node.level and not node.module):
                found += [(f"{target}.{alias.name}", node.lineno) for alias in node.names]
            else:
                found.append((target, node.lineno))
    return [(name, line) for name, line in found if name.split(".")[0] == "depthguard"]


_MODULE_PATH = re.compile(r"depthguard(\.\w+)+(:\w+)?")


def string_imports(source: str) -> list[tuple[str, int]]:
    """Module paths given as a whole string (``"depthguard.viz.live:open_view"``,
    ``"depthguard.sources.images"``): a registry's entry points, imported later with
    ``importlib``; they count as imports of that module, ``(dotted name, line)``."""
    return [(node.value.partition(":")[0], node.lineno) for node in ast.walk(ast.parse(source))
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and _MODULE_PATH.fullmatch(node.value)]


def room_of(dotted: str) -> str | None:
    """The room of a ``depthguard`` module: its top-level module or sub-package; None for the
    package root."""
    parts = dotted.split(".")
    return parts[1] if len(parts) > 1 else None


def _rooms_present() -> set[str]:
    rooms = set()
    for path in PACKAGE.iterdir():
        if path.suffix == ".py" and path.stem != "__init__":
            rooms.add(path.stem)
        elif path.is_dir() and (path / "__init__.py").exists():
            rooms.add(path.name)
    return rooms


def back_up_imports() -> list[tuple[str, int, str]]:
    """``(importer, line, imported)`` for every import of a room later in LAYERS than the
    importer's own room."""
    rank = {room: i for i, room in enumerate(LAYERS)}
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module, is_init = _module_name(path)
        here = room_of(module)
        if here is None:
            continue
        text = path.read_text(encoding="utf-8")
        for target, line in imported_modules(text, module, is_init) + string_imports(text):
            there = room_of(target)
            if there is None or there == here or there not in rank or here not in rank:
                continue
            if rank[there] > rank[here]:
                found.append((module, line, target))
    return found


# ------------------------------------------------------------------ the walker
def test_walker_finds_every_form_of_import():
    source = (
        "import numpy as np\n"
        "import depthguard.camera\n"
        "from depthguard.fusion.voxels import VoxelSet\n"
        "from depthguard import sources, __version__\n"
        "def f():\n"
        "    from depthguard.runtime.joints import JointHistory\n"
        "    class A:\n"
        "        def g(self):\n"
        "            import depthguard.sim.cells as cells\n"
        "from . import noise\n"
        "from ..render import Renderer\n"
    )
    got = imported_modules(source, "depthguard.sources.simulated")
    assert [name for name, _ in got] == [
        "depthguard.camera", "depthguard.fusion.voxels", "depthguard.sources", "depthguard.__version__",
        "depthguard.sources.noise", "depthguard.render", "depthguard.runtime.joints", "depthguard.sim.cells"]
    assert dict(got)["depthguard.runtime.joints"] == 6
    assert [room_of(n) for n, _ in got] == ["camera", "fusion", "sources", "__version__", "sources", "render",
                                           "runtime", "sim"]
    # in a package's __init__, `from . import x` is that package's x
    assert imported_modules("from . import base\n", "depthguard.sources", is_init=True) == [
        ("depthguard.sources.base", 1)]
    assert room_of("depthguard") is None


def test_walker_counts_module_paths_given_as_strings():
    """A registry's entry point named by string (imported later by importlib) is an import too;
    a docstring that mentions a module is not."""
    source = (
        '"""Sinks: :mod:`depthguard.viz.live` is the view."""\n'
        'SCHEMES = {"jsonl": "depthguard.runtime.sinks:open_jsonl", "view": "depthguard.viz.live:open_view"}\n'
        'MODULES = ["depthguard.sources.images"]\n'
    )
    assert string_imports(source) == [("depthguard.runtime.sinks", 2), ("depthguard.viz.live", 2),
                                      ("depthguard.sources.images", 3)]


def test_walker_sees_a_lazy_import_of_the_real_tree():
    """A known lazy import of the package (inside a method) is found by the walk: the walk
    is not blind to imports inside functions."""
    path = PACKAGE / "runtime" / "ingest.py"
    module, is_init = _module_name(path)
    names = [name for name, _ in imported_modules(path.read_text(encoding="utf-8"), module, is_init)]
    assert "depthguard.runtime.scene_change" in names    # in CameraWorker.__init__, not at module level
    assert module == "depthguard.runtime.ingest" and not is_init


# ------------------------------------------------------------------ the order
def test_every_room_is_placed_once():
    assert len(set(LAYERS)) == len(LAYERS)
    present = _rooms_present()
    assert present - set(LAYERS) == set(), "rooms missing from depthguard.layers.LAYERS"
    assert set(LAYERS) - present == set(), "LAYERS names rooms that do not exist"


def test_no_import_runs_back_up():
    found = back_up_imports()
    print(f"\n{len(found)} imports run back up the layers:")
    for module, line, target in found:
        print(f"  {module}:{line} imports {target}")
    unexplained = [(m, line, t) for m, line, t in found if (m, t) not in ALLOWED]
    assert unexplained == [], "\n".join(f"{m}:{line} imports {t}, a room above it (depthguard.layers)"
                                        for m, line, t in unexplained)


def test_each_exception_is_still_needed_and_documented():
    assert len(ALLOWED) <= 2
    found = {(m, t) for m, _, t in back_up_imports()}
    architecture = (PACKAGE.parent.parent / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
    for module, target in ALLOWED:
        assert (module, target) in found, f"{module} no longer imports {target}: drop it from ALLOWED"
        assert module.replace("depthguard.", "").replace(".", "/") in architecture


def test_architecture_states_the_same_order():
    """docs/ARCHITECTURE.md ("Import graph") lists the rooms in the order of LAYERS."""
    text = (PACKAGE.parent.parent / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
    block = text[text.index("\nImport graph"):].split("\n\n")[1]
    stated = [room.strip() for room in block.replace("\n", " ").split("→")]
    assert stated == list(LAYERS)
