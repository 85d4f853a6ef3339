"""Issue 20, first contact: what a new user types first gives a sentence, not a surprise.

``depthguard --version`` exists; no flag shows a ``<bool>`` value placeholder in ``--help``;
``print(rig)`` is one short line; the README's commands are commands the CLI accepts, its
links stay inside the repository, and it states the demo's duration once, as the demo's
``--help`` does. Each failed on the code before the fix.
"""

import re
import shlex
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest
from typer import Exit
from typer.main import get_command
from typer.testing import CliRunner

from depthguard.cli import app

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_version_prints_the_installed_version():
    res = subprocess.run([sys.executable, "-m", "depthguard.cli", "--version"], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"depthguard {version('depthguard')}"


def _commands(command, path=()):
    yield path, command
    for name, sub in getattr(command, "commands", {}).items():
        yield from _commands(sub, path + (name,))


def test_no_flag_shows_a_bool_placeholder_in_help():
    runner = CliRunner()
    seen = 0
    for path, _ in _commands(get_command(app)):
        r = runner.invoke(app, [*path, "--help"], terminal_width=200)
        assert r.exit_code == 0, (path, r.output)
        assert "--help" in r.output
        assert "<bool>" not in r.output, f"depthguard {' '.join(path)} --help shows <bool>"
        seen += 1
    assert seen > 10          # every command and sub-command was looked at


def test_a_value_option_keeps_its_placeholder():
    r = CliRunner().invoke(app, ["distance", "--help"], terminal_width=200)
    assert "<float>" in r.output and "CAMERA=FILE" in r.output      # --rho, --depth


def test_print_rig_is_one_short_line():
    from depthguard.sim import load_cell

    rig = load_cell("c-arm-room").rig             # 21 cameras, 18 objects with their meshes
    text = repr(rig)
    assert "\n" not in text and len(text) < 600, text
    assert "array(" not in text
    assert all(c.id in text for c in rig.cameras) and rig.objects[0].name in text
    assert "\n" not in repr(rig.objects[0]) and "array(" not in repr(rig.objects[0])


# ------------------------------------------------------------------------- README
def _readme_commands():
    """Every ``.venv/bin/depthguard ...`` line of the README's shell blocks, as argument lists."""
    out, fence = [], None
    for line in (ROOT / "README.md").read_text().splitlines():
        if line.startswith("```"):
            fence = None if fence is not None else (line[3:].strip() or "sh")
            continue
        if fence in ("sh", "bash", "console"):
            m = re.match(r"^\.venv/bin/depthguard\b(.*)$", re.split(r"\s#\s", line, maxsplit=1)[0].strip())
            if m:
                out.append(shlex.split(m.group(1)))
    return out


def test_the_readme_has_commands_to_check():
    assert len(_readme_commands()) >= 10


@pytest.mark.parametrize("args", _readme_commands(), ids=lambda a: " ".join(a)[:60])
def test_every_readme_command_parses(args):
    """Each command line of the README names a command and options the CLI has, with values it
    accepts (the option parser's own check; nothing runs)."""
    group = get_command(app)
    try:
        ctx = group.make_context("depthguard", list(args), resilient_parsing=False)
        rest = _unparsed(ctx)
        command = group
        while rest and hasattr(command, "commands"):
            name, rest = rest[0], rest[1:]
            assert name in command.commands, f"README: no command {name!r} in {args}"
            command = command.commands[name]
            ctx = command.make_context(name, rest, parent=ctx, resilient_parsing=False)
            rest = _unparsed(ctx)
    except Exit as done:                 # --help, --version: printed, status 0
        assert done.exit_code == 0
        return
    assert not rest, f"README: left over {rest} in {args}"


def _unparsed(ctx):
    return list(getattr(ctx, "_protected_args", [])) + list(ctx.args)


def test_the_readme_node_command_names_its_cell():
    """``node --source sim`` simulates the camera of a built-in cell and needs ``--cell``."""
    nodes = [a for a in _readme_commands() if a[:1] == ["node"]]
    assert nodes
    for a in nodes:
        if "--source" not in a or a[a.index("--source") + 1] == "sim":
            assert "--cell" in a, a


def test_no_doc_links_outside_the_repository():
    for doc in DOCS:
        assert "../shared" not in doc.read_text(), f"{doc.name} points outside the repository"


def test_every_requirement_the_docs_cite_is_in_the_repository():
    cited = set()
    for doc in DOCS:
        cited |= set(re.findall(r"\bR(\d{1,2})\b", doc.read_text()))
    reqs = (ROOT / "docs" / "REQUIREMENTS.md").read_text()
    listed = set(re.findall(r"^\| R(\d{1,2}) \|", reqs, flags=re.M))
    assert cited and cited <= listed, sorted(cited - listed, key=int)


def test_the_demo_duration_is_stated_once_and_alike():
    """The README states how long `make demo` takes in one sentence (first run, later runs);
    ``depthguard demo --help`` says the same; no other duration of the demo is left."""
    readme = (ROOT / "README.md").read_text()
    stated = re.findall(r"`make demo` takes about (\d+) min on this 2-core machine the first time"
                        r".*?about (\d+) min\s+every time after", readme, flags=re.S)
    assert len(stated) == 1, stated
    first, after = stated[0]
    part = readme[readme.index("## What `make demo` does"):readme.index("## Your cell")]
    assert not re.search(r"about (a minute|\d+ s\b)|takes about \d+ s", part)
    r = CliRunner().invoke(app, ["demo", "--help"], terminal_width=300)
    text = " ".join(r.output.replace("│", " ").split())
    assert f"About {after} min" in text and f"{first} min the first time" in text, text
