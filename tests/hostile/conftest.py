"""The inputs every hostile case starts from, built once per session (:mod:`.inputs`)."""
from __future__ import annotations

import pytest

from .inputs import Inputs, build_inputs


@pytest.fixture(scope="session")
def hostile_inputs(tmp_path_factory) -> Inputs:
    return build_inputs(tmp_path_factory.mktemp("hostile") / "in")
