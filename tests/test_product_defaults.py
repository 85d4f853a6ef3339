"""The product's defaults are defined once (issue 28): the library's functions default to
:class:`~depthguard.config.MonitorConfig`'s values, so a caller that leaves a setting out gets
what the product runs with. Truth: the signatures themselves (``inspect``), against the
config model's field defaults; and no signature in ``src/`` repeats one of them as a literal (it
takes ``config.PRODUCT_*`` or no default) nor gives ``rho`` or ``robot_offset`` a number of its
own (``robot_offset=0.03`` once contradicted the product's 0.08). Truth: the source's syntax
tree (``ast``)."""

from __future__ import annotations

import ast
import inspect
import pathlib

import pytest

from depthguard.config import MonitorConfig
from depthguard.distance.api import DistanceWorkspace, depth_space_distance
from depthguard.distance.cartesian import CartesianBaseline
from depthguard.distance.reference import obstacle_start_depth_numpy


@pytest.mark.parametrize("fn", [DistanceWorkspace.set_depth, depth_space_distance, CartesianBaseline.set_depth,
                                obstacle_start_depth_numpy], ids=lambda f: f.__qualname__)
def test_self_removal_offset_is_the_products(fn):
    default = inspect.signature(fn).parameters["robot_offset"].default
    assert default == MonitorConfig().robot_offset == 0.08          # R9 (config.PRODUCT_ROBOT_OFFSET)


@pytest.mark.parametrize("fn", [DistanceWorkspace.query, depth_space_distance], ids=lambda f: f.__qualname__)
def test_radius_of_surveillance_is_the_products(fn):
    assert inspect.signature(fn).parameters["rho"].default == MonitorConfig().rho


SRC = pathlib.Path(__file__).resolve().parents[1] / "src" / "depthguard"

#: where a literal may stay for now (a file other work rebuilds at present); none left (issue 28 item 5)
PENDING: set[str] = set()
#: any literal default of these contradicts or repeats the product's
NEVER_LITERAL = ("rho", "robot_offset")


def product_defaults() -> dict:
    out = {}
    for name, f in MonitorConfig.model_fields.items():
        d = f.default
        if isinstance(d, (int, float, str)) and not isinstance(d, bool):
            out[name] = d
    return out


def literal_defaults(tree):
    """(line, function, parameter, value) of every constant default of a function parameter (also
    a CLI option's, the first argument of ``typer.Option``)."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            pos = a.posonlyargs + a.args
            pairs = list(zip(pos[len(pos) - len(a.defaults):], a.defaults))
            pairs += [(x, d) for x, d in zip(a.kwonlyargs, a.kw_defaults) if d is not None]
            for arg, d in pairs:
                if isinstance(d, ast.Call) and d.args:        # a command's option: typer.Option(default, ...)
                    d = d.args[0]
                if isinstance(d, ast.Constant) and not isinstance(d.value, bool):
                    yield node.lineno, node.name, arg.arg, d.value


def offenders(files, root=SRC) -> list[str]:
    prod = product_defaults()
    out = []
    for path in files:
        rel = path.relative_to(root).as_posix()
        if rel == "config.py":
            continue
        for line, fn, arg, value in literal_defaults(ast.parse(path.read_text(encoding="utf-8"))):
            repeats = arg in prod and value == prod[arg] and type(value) is type(prod[arg])
            own = arg in NEVER_LITERAL and isinstance(value, (int, float))
            if repeats or own:
                out.append(f"{rel}:{line} {fn}({arg}={value!r})")
    return out


def test_no_library_signature_repeats_a_product_default():
    files = [p for p in sorted(SRC.rglob("*.py")) if p.relative_to(SRC).as_posix() not in PENDING]
    found = offenders(files)
    assert not found, "take depthguard.config.PRODUCT_* (or no default):\n" + "\n".join(found)


def test_the_check_finds_a_repeated_and_a_contradicting_default(tmp_path):
    bad = tmp_path / "_probe_defaults.py"
    bad.write_text('def f(points, rho: float = 0.4, method="hybrid", robot_offset=0.03, n=3,\n'
                   '      invalid=typer.Option("unknown", "--invalid")):\n    pass\n')
    found = offenders([bad], root=tmp_path)
    assert found == ["_probe_defaults.py:1 f(rho=0.4)", "_probe_defaults.py:1 f(method='hybrid')",
                     "_probe_defaults.py:1 f(robot_offset=0.03)", "_probe_defaults.py:1 f(invalid='unknown')"]
