"""The inputs every hostile case starts from, built once per session (:mod:`.inputs`)."""
from __future__ import annotations

import pytest

from ..conftest import built_once
from .inputs import Inputs, build_inputs


@pytest.fixture(scope="session")
def hostile_inputs(tmp_path_factory) -> Inputs:
    """Built once per run (``built_once``: three files read them, on either worker); every case copies or reads."""
    return built_once(tmp_path_factory, "hostile", lambda folder: build_inputs(folder / "in"))
