"""docs/inputs.md is true to the code: its generated part (the table of every input file and the field tables) is
what the schemas say now, every schema and every test file it names exists, and the README links to it."""
from __future__ import annotations

import re

from .input_schemas import FILES, OTHER_INPUTS, PAGE, ROOT, generated_part, render


def test_the_page_matches_the_schemas():
    page = PAGE.read_text(encoding="utf-8")
    assert generated_part(page) == render(), "docs/inputs.md is stale: run `python -m tests.input_schemas`"


def test_every_file_and_test_it_names_exists():
    from dome_calib.schema import describe_schema

    for f in FILES:
        assert describe_schema(f.schema()), f.name  # a schema with fields (a RootModel's start at <name>)
    named = set(re.findall(r"tests/\w+\.py", render()))
    assert {"tests/test_input_mutations.py", "tests/test_inputs_cli.py"} <= named
    missing = sorted(t for t in named if not (ROOT / t).is_file())
    assert not missing, missing
    for row in OTHER_INPUTS:
        for dotted in re.findall(r"`(dome_calib\.[\w.]+|timecode\.[\w.]+)`", row[3]):
            module, _, name = dotted.rpartition(".")
            import importlib

            assert hasattr(importlib.import_module(module), name), dotted


def test_the_readme_links_the_page():
    assert "(docs/inputs.md)" in (ROOT / "README.md").read_text(encoding="utf-8")
