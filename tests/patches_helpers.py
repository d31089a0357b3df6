"""The capture the patch tests share: the tiny dome with synthetic sync tables (0-1.5 s) and one person talking
(scenario ``conversation``, 0.1-1.4 s, seed 2), the group's truth with its textured surface to render."""
from __future__ import annotations

from dome_calib.bundle import Bundle
from dome_calib.synth.dome import nominal_dome
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.skeleton import synthetic_sync


def one_person_capture():
    """(bundle, truth): the tiny dome (seed 0) with sync tables, and one person's truth (``make_group``)."""
    bundle: Bundle = nominal_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=1500.0, seed=0)
    truth = make_group(GroupOptions(n_people=1, scenario="conversation", start_ms=100.0, duration_ms=1300.0, seed=2))
    return bundle, truth
