"""Runs ``depthguard`` command lines one after another in one Python process, as a shell would run
them one process each, for tests/test_own_cell_tutorial.py: ``python tutorial_shell.py RESULTS
LINE...``. Each line goes through the program's own entry point (:func:`depthguard.cli.main`, with
``sys.argv`` set from the line); its exit status is what that process would have returned (the
``SystemExit`` code; an exception that escapes is printed as Python prints it and counts as 1), and
everything it writes to file descriptors 1 and 2 (Python, native code, child processes) goes to
files of its own. RESULTS gets a JSON list ``[{"line", "code", "stdout", "stderr", "cpu_s"}, ...]``; the
lines after a failing one are not run. One process instead of one per line: the package's import
and numba's cache load happen once (about 5 CPU-s a command)."""

from __future__ import annotations

import json
import os
import resource
import shlex
import sys
import tempfile
import traceback


def run_line(line: str, out_path: str, err_path: str) -> int:
    args = shlex.split(line)
    if not args or args[0] != "depthguard":
        raise SystemExit(f"not a depthguard command: {line!r}")
    from depthguard.cli import main

    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(out_path, "wb") as out, open(err_path, "wb") as err:
        os.dup2(out.fileno(), 1)
        os.dup2(err.fileno(), 2)
        sys.argv = ["depthguard", *args[1:]]
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            if exc.code is not None and not isinstance(exc.code, int):
                print(exc.code, file=sys.stderr)
        except BaseException:                      # noqa: BLE001 - what the interpreter would print
            traceback.print_exc()
            code = 1
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
    return code


def _cpu() -> float:
    """CPU seconds (user + system) of this process and of its children that ended."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def main(results: str, lines: list[str]) -> None:
    done = []
    with tempfile.TemporaryDirectory(prefix="tutorial-shell-") as tmp:
        for i, line in enumerate(lines):
            out, err = os.path.join(tmp, f"{i}.out"), os.path.join(tmp, f"{i}.err")
            c0 = _cpu()
            code = run_line(line, out, err)
            cpu = _cpu() - c0
            with open(out, errors="replace") as fo, open(err, errors="replace") as fe:
                done.append({"line": line, "code": code, "stdout": fo.read(), "stderr": fe.read(),
                             "cpu_s": round(cpu, 2)})
            if code != 0:
                break
    with open(results, "w") as fh:
        json.dump(done, fh)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
