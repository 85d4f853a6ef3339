"""Issue 33 item 14: every ``make`` printed setuptools' licence deprecation banner twice.

The cause was the licence written as a table (``license = {text = ...}``), which setuptools
deprecates from version 77 on in favour of an SPDX expression (PEP 639). The truth here is the
packaging library's own SPDX parser and its version comparison, not a string of ours."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.licenses import canonicalize_license_expression
from packaging.requirements import Requirement
from packaging.version import Version

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def test_the_licence_is_an_spdx_expression_that_the_build_backend_reads_without_a_warning():
    data = tomllib.loads(PYPROJECT.read_text())
    lic = data["project"]["license"]
    assert isinstance(lic, str), f"project.license is {lic!r}: a table is deprecated (setuptools >= 77 warns)"
    assert canonicalize_license_expression(lic) == lic          # a valid SPDX expression, as written
    # the backend must be one that reads the string form (setuptools 77 and later)
    reqs = [Requirement(r) for r in data["build-system"]["requires"]]
    st = [r for r in reqs if r.name == "setuptools"]
    assert st and not st[0].specifier.contains(Version("76.9")), \
        f"build-system requires {st[0] if st else 'no setuptools'}: a string licence needs setuptools >= 77"
    assert data["build-system"]["build-backend"] == "setuptools.build_meta"
