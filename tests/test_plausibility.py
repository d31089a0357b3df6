"""Issue 50, plausibility across files: numbers each fine alone but of another unit or another session. Before
(main at aaf6910): sync tables in seconds were taken (the body over time came out 4x worse in silence); a stream
whose sync table missed the reference times contributed nothing while the summary counted its cameras; an import
1000x off in unit (a file in mm read as m: a 5 km dome; Qualisys in m; Kalibr in mm) was taken without a word."""
from __future__ import annotations

import json
import logging
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from dome_calib.bundle import Bundle
from dome_calib.bundle_io import write_bundle
from dome_calib.interop.common import ImportOptions
from dome_calib.interop.convert import read_foreign
from dome_calib.layout import nominal_dome
from dome_calib.synth.detector import write_openpose_folder

from .interop_helpers import kalibr_camchain
from .people_helpers import group_detections
from .recon_helpers import real_bundle

QCA = Path(__file__).parent / "data" / "pose2sim_qualisys" / "Calib.qca.txt"


def _one_line(out, *named: str) -> str:
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 1 and len(lines) == 1 and lines[0].startswith("dome-calib: error:"), out.stderr[-3000:]
    assert all(n in lines[0] for n in named), lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def synced(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("synced") / "b"
    write_bundle(real_bundle(kinect=True, n_vga=4, duration_ms=400.0), folder)
    return folder


def _edit(path: Path, change) -> None:
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


@pytest.mark.parametrize("file, stream, scale, unit", [
    ("synctables", "vga", 1e-3, "seconds"), ("synctables", "hd", 1e-3, "seconds"),
    ("synctables", "vga", 1e3, "microseconds"), ("ksynctables", "color", 1e-3, "seconds"),
    ("ksynctables", "depth", 1e3, "microseconds")])
def test_sync_tables_not_in_milliseconds_are_refused(synced, file, stream, scale, unit, dome_calib_cli, tmp_path):
    folder = shutil.copytree(synced, tmp_path / "b")
    path = next(folder.glob(f"{file}_*.json"))

    def change(doc):
        table = doc[stream] if file == "synctables" else doc["kinect"][stream]["KINECTNODE1"]
        table["univ_time"] = [t * scale for t in table["univ_time"]]

    _edit(path, change)
    line = _one_line(dome_calib_cli("info", str(folder)), path.name, "univ_time", f"are these {unit}?")
    assert "ms apart" in line


def test_a_stream_of_another_name_in_seconds_is_refused(synced, dome_calib_cli, tmp_path):
    folder = shutil.copytree(synced, tmp_path / "b")
    path = next(folder.glob("synctables_*.json"))
    _edit(path, lambda d: d.update(extra={"index": [0, 1, 2], "univ_time": [1.0, 1.04, 1.08]}))
    _one_line(dome_calib_cli("info", str(folder)), "extra.univ_time", "are these seconds?")


def test_a_stream_that_misses_the_reference_times_is_said_and_not_counted(dome_calib_cli, tmp_path, caplog):
    """The HD stream's table moved 1000 s later (another session's): its 2 cameras cannot be interpolated at any
    VGA time; the summary counted them ("from 6 cameras") and said nothing."""
    full = real_bundle(kinect=False, n_vga=40, start_ms=1000.0, duration_ms=400.0, seed=3)
    vga = sorted(full.of_type("vga"))[::10][:4]
    hd = ["00_03", "00_10"]
    bundle = Bundle(seq=full.seq, cameras={n: full.cameras[n] for n in vga + hd}, sync=full.sync)
    people, _ = group_detections(bundle, sorted(bundle.cameras), 2, seed=4)
    write_openpose_folder(tmp_path / "det", people, body_model="COCO_18")
    write_bundle(bundle, tmp_path / "b")
    _edit(next((tmp_path / "b").glob("synctables_*.json")),
          lambda d: d["hd"].update(univ_time=[t + 1e6 for t in d["hd"]["univ_time"]]))
    with caplog.at_level(logging.WARNING):
        out = dome_calib_cli("reconstruct", str(tmp_path / "det"), "--bundle", str(tmp_path / "b"), "-o",
                             str(tmp_path / "out"))
    assert out.returncode == 0, out.stderr[-2000:]
    assert "from 4 cameras" in out.stdout, out.stdout
    said = [r.getMessage() for r in caplog.records if "stream hd" in r.getMessage()]
    assert len(said) == 1 and "00_03, 00_10" in said[0] and "not used" in said[0], said


# ---- imports a 1000x off in unit -----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("tiny") / "b"
    write_bundle(nominal_dome("tiny", seed=0), folder)
    return folder


def _warned(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "than any rig" in r.getMessage()]


@pytest.mark.parametrize("fmt", ["colmap", "aniposelib"])
def test_a_file_read_in_the_wrong_unit_warns_naming_unit(tiny, fmt, dome_calib_cli, tmp_path, caplog):
    """Written in mm, read as m: a 4 km dome (and the other way, 4 mm); read right: no warning."""
    for written, read, size in (("mm", "m", "larger"), ("m", "mm", "smaller"), ("m", "m", None)):
        src = tmp_path / f"{written}-as-{read}.{'toml' if fmt == 'aniposelib' else 'model'}"
        assert dome_calib_cli("export", str(tiny), "--to", fmt, "-o", str(src), "--unit", written).returncode == 0
        if fmt == "aniposelib":  # a file of aniposelib's own (ours records the unit in [metadata])
            src.write_text(re.sub(r"\[metadata\][^\[]*", "", src.read_text()))
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            read_foreign(src, fmt, ImportOptions(unit=read))
        said = _warned(caplog)
        if size is None:
            assert said == []
        else:
            assert len(said) == 1 and size in said[0] and "--unit" in said[0], said


def test_a_qualisys_file_in_metres_warns(tmp_path, caplog):
    """Qualisys files are in mm by the format: one in m reads 1000x too small."""
    text = QCA.read_text()
    text = re.sub(r'(\b[xyz]\b)="(-?[\d.]+)"', lambda m: f'{m.group(1)}="{float(m.group(2)) / 1000:.9g}"', text)
    (tmp_path / "Calib.qca.txt").write_text(text)
    with caplog.at_level(logging.WARNING):
        read_foreign(tmp_path / "Calib.qca.txt", "qualisys")
    said = _warned(caplog)
    assert len(said) == 1 and "smaller" in said[0] and "--unit" in said[0], said


def test_a_kalibr_file_in_millimetres_warns(tmp_path, caplog):
    """Kalibr files are in m: one whose translations are mm reads 1000x too large."""
    dome = nominal_dome("tiny", seed=1)
    doc = kalibr_camchain([dome.cameras[n] for n in ("00_00", "01_01", "50_04")])
    for entry in doc.values():
        if "T_cn_cnm1" in entry:
            T = np.asarray(entry["T_cn_cnm1"])
            T[:3, 3] *= 1000.0
            entry["T_cn_cnm1"] = T.tolist()
    (tmp_path / "camchain.yaml").write_text(yaml.dump(doc))
    with caplog.at_level(logging.WARNING):
        read_foreign(tmp_path / "camchain.yaml", "kalibr")
    said = _warned(caplog)
    assert len(said) == 1 and "larger" in said[0] and "--unit" in said[0], said


def test_triangulate_names_a_stream_that_misses_every_time(dome_calib_cli, tmp_path, caplog):
    """The same rule for `triangulate`: a stream whose detected frames reach none of the times is named once and
    left out of the summary's streams (before: listed as if it contributed)."""
    from dome_calib.synth.skeleton import synthetic_tracks  # noqa: PLC0415

    bundle = real_bundle(n_vga=20, start_ms=1000.0, duration_ms=400.0, seed=7)
    write_bundle(bundle, tmp_path / "b")
    cams = {}
    for s in synthetic_tracks(bundle, sorted(bundle.of_type("vga"))[:6] + ["00_03", "00_10"], seed=8):
        for v, name in enumerate(s.cameras):
            joints = np.concatenate([np.nan_to_num(s.uv_px[:, v], nan=0.0), s.conf[:, v, :, None]], axis=-1)
            cams[name] = {"frames": s.frame_index.tolist(), "joints": np.round(joints, 3).tolist()}
    (tmp_path / "det.json").write_text(json.dumps({"joints": 19, "cameras": cams}))
    _edit(next((tmp_path / "b").glob("synctables_*.json")),
          lambda d: d["hd"].update(univ_time=[t + 1e6 for t in d["hd"]["univ_time"]]))
    with caplog.at_level(logging.WARNING):
        out = dome_calib_cli("triangulate", str(tmp_path / "det.json"), "--bundle", str(tmp_path / "b"), "-o",
                             str(tmp_path / "sk"))
    assert out.returncode == 0, out.stderr[-2000:]
    assert "from streams vga:" in out.stdout, out.stdout
    said = [r.getMessage() for r in caplog.records if "stream hd" in r.getMessage()]
    assert len(said) == 1 and "contribute nothing" in said[0], said
