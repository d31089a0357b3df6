"""People-out test data and the peers' own readers: body3DScene folders of the demo's synthetic group and of the
real Pose2Sim capture, and each output read back by the tool it is written for (OpenSim's ``TRCFileAdapter``,
Pose2Sim's ``read_trc``, ezc3d, the ``c3d`` package, bvhio)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dome_calib.skeletons.joints import PARENT
from dome_calib.skeletons.scenes import People
from dome_calib.synth.group import GroupOptions, make_group
from dome_calib.synth.skeleton import FEET, feet_cm  # noqa: F401  (the tests' feet)

DATA = Path(__file__).parent / "data" / "pose2sim_balancing"
CAMERA_MAP = ",".join(f"cam{k:02d}_json=00_{k:02d}" for k in range(1, 5))


def write_scenes(folder: Path, frames, times_ms, bodies, *, fps_type: str = "vga_25", layout: str = "joints19",
                 extra: tuple[str, ...] = (), body_model: str | None = None) -> Path:
    """body3DScene files: ``bodies[k]`` = {id: (J, 4) [x, y, z, c]} at frame ``frames[k]`` (c < 0: missing, written
    as Panoptic writes it: 0, 0, 0, -1); with ``extra`` joint names, the last ``len(extra)`` rows go to
    ``extraJoints`` as ``reconstruct`` writes them."""
    folder.mkdir(parents=True, exist_ok=True)
    for frame, t, people in zip(frames, times_ms, bodies):
        out = []
        for pid, j in sorted(people.items()):
            j = np.where(j[:, 3:] < 0, [0.0, 0.0, 0.0, -1.0], j)
            n = len(j) - len(extra)
            body = {"id": int(pid), layout: [round(float(v), 4) for v in j[:n].ravel()]}
            if extra:
                body["extraJoints"] = [round(float(v), 4) for v in j[n:].ravel()]
            out.append(body)
        doc = {"version": 0.7, "univTime": round(float(t), 4), "fpsType": fps_type}
        if extra:
            doc |= {"bodyModel": body_model, "extraJointNames": list(extra)}
        doc["bodies"] = out
        (folder / f"body3DScene_{int(frame):08d}.json").write_text(json.dumps(doc), encoding="utf-8")
    return folder


def demo_group_scenes(folder: Path, *, n_people: int = 7, seconds: float = 4.0, seed: int = 0,
                      drop: float = 0.03, feet: bool = False) -> Path:
    """The demo's synthetic group (7 people, "mixed": walking past, talking, crouching, leaving, entering; seed 0)
    at VGA frames (25 fps) from frame 250, as body3DScene files with confidence 0.9, and a share ``drop`` of the
    joints written as not reconstructed (c = -1). Its bones are constant by construction. ``feet``: BODY_25's six
    foot joints beside joints19 (:func:`feet_cm`), as ``reconstruct`` writes a BODY_25 detector's."""
    truth = make_group(GroupOptions(n_people=n_people, duration_ms=seconds * 1000.0, start_ms=10_000.0, seed=seed))
    frames = np.arange(250, 250 + int(seconds * 25))
    times = 10_000.0 + (frames - 250) * 40.0
    X, present = truth.joints_cm(times)
    rng = np.random.default_rng(seed)
    bodies = []
    for k in range(len(frames)):
        people = {}
        for p in np.flatnonzero(present[k]):
            joints = np.concatenate([X[k, p], feet_cm(X[k, p])]) if feet else X[k, p]
            c = np.where(rng.random(len(joints)) < drop, -1.0, 0.9)
            people[int(truth.ids[p])] = np.concatenate([joints, c[:, None]], axis=1)
        bodies.append(people)
    return write_scenes(folder, frames, times, bodies, extra=FEET if feet else (), body_model="BODY_25")


def real_capture_scenes(root: Path) -> Path:
    """The real Pose2Sim capture (4 phone cameras, one participant, 100 frames at 60 fps) imported as ``dome-calib
    import --from pose2sim`` does (its z-up world turned into ours) and reconstructed as ``dome-calib reconstruct``
    does (BODY_25B, the cameras mapped): its body3DScene folder."""
    from dome_calib.interop.common import ImportOptions
    from dome_calib.interop.convert import import_calibration
    from dome_calib.recon.people.commands import people_options, reconstruct_folder

    names = {f"cam_{k:02d}": f"00_{k:02d}" for k in range(1, 5)}
    import_calibration(DATA / "calibration" / "Calib_qualisys.toml", "pose2sim", root / "bundle",
                       ImportOptions(names=names, seq="balancing"))
    reconstruct_folder(DATA / "pose", root / "bundle", root / "people", body_model="BODY_25B", camera_map=CAMERA_MAP,
                       options=people_options(fps="60"))
    return root / "people"


def ours_dense(people: People, pid: int, frames: np.ndarray, M: np.ndarray, scale: float) -> np.ndarray:
    """Our joints of person ``pid`` at ``frames`` (file numbers), in another tool's axes (``M``) and units
    (``scale`` per cm), NaN where missing or absent."""
    track = people.tracks[pid]
    out = np.full((len(frames), len(people.joints), 3), np.nan)
    at = {int(f): k for k, f in enumerate(frames)}
    out[[at[int(f)] for f in people.frames[track.rows]]] = track.X_cm @ M.T * scale
    return out


def chain_present(people: People, X: np.ndarray) -> np.ndarray:
    """(F, J): the joint and every joint up its chain to the root are reconstructed in ``X`` (F, J, 3)."""
    ok = np.isfinite(X).all(-1)
    out = ok.copy()
    for k, name in enumerate(people.joints):
        parent = PARENT[name]
        while parent is not None:
            out[:, k] &= ok[:, people.joints.index(parent)]
            parent = PARENT[parent]
    return out


# ---- the peers' readers ------------------------------------------------------------------------------------------

def opensim_trc(path: Path) -> dict:
    """A TRC file through OpenSim's own reader (``TimeSeriesTableVec3`` -> ``TRCFileAdapter``)."""
    import opensim

    table = opensim.TimeSeriesTableVec3(str(path))
    labels = list(table.getColumnLabels())
    times = np.array([table.getIndependentColumn()[r] for r in range(table.getNumRows())])
    X = np.array([[[table.getRowAtIndex(r)[c].get(i) for i in range(3)] for c in range(len(labels))]
                  for r in range(table.getNumRows())])
    return {"markers": labels, "times_s": times, "X": X, "units": table.getTableMetaDataAsString("Units"),
            "rate": float(table.getTableMetaDataAsString("DataRate"))}


def pose2sim_trc(path: Path) -> dict:
    """A TRC file through Pose2Sim's own reader (``Pose2Sim.common.read_trc``)."""
    from Pose2Sim.common import read_trc

    data, frames, times, markers, _ = read_trc(str(path))
    return {"markers": markers, "frames": frames.to_numpy(), "times_s": times.to_numpy(),
            "X": data.to_numpy(dtype=float).reshape(len(data), len(markers), 3)}


def ezc3d_read(path: Path) -> dict:
    import ezc3d

    c = ezc3d.c3d(str(path))
    p = c["parameters"]
    return {"labels": list(p["POINT"]["LABELS"]["value"]), "rate": c["header"]["points"]["frame_rate"],
            "units": p["POINT"]["UNITS"]["value"][0], "first_frame": c["header"]["points"]["first_frame"],
            "X": c["data"]["points"][:3].transpose(2, 1, 0),
            "subjects": list(p["SUBJECTS"]["NAMES"]["value"]), "y_screen": p["POINT"]["Y_SCREEN"]["value"][0]}


def c3d_package_read(path: Path) -> dict:
    """A C3D file through the ``c3d`` package (Pose2Sim's C3D library; another implementation than ezc3d)."""
    import warnings

    import c3d

    with open(path, "rb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no analog data": a motion-capture file without force plates
        reader = c3d.Reader(f)
        frames = [(i, p.copy()) for i, p, _ in reader.read_frames()]
        labels = [s.strip() for s in reader.point_labels]
        return {"labels": labels, "first_frame": reader.first_frame, "frames": np.array([i for i, _ in frames]),
                "X": np.array([p[:, :3] for _, p in frames]), "residual": np.array([p[:, 3] for _, p in frames])}


def bvhio_positions(path: Path, names: list[str]) -> tuple[float, np.ndarray]:
    """(frame time, (F, len(names), 3)) world positions of the named joints of a BVH file, through bvhio's own
    forward kinematics."""
    import bvhio

    root = bvhio.readAsHierarchy(str(path))
    by_name = {j.Name: j for j, _, _ in root.layout()}
    F = len(root.Keyframes)
    out = np.zeros((F, len(names), 3))
    for f in range(F):
        root.loadPose(f, recursive=True)
        out[f] = [tuple(by_name[n].PositionWorld) for n in names]
    return bvhio.readAsBvh(str(path), loadKeyFrames=False).FrameTime, out


def demo_group_reconstructed(tmp_path_factory) -> Path:
    """The demo's group (7 people, "mixed", seed 0) seen by the tiny dome as built (16 cameras, sync tables) through
    its synthetic OpenPose detector, reconstructed as ``dome-calib reconstruct`` does: a folder holding ``bundle/``,
    ``session/detections/`` and ``people/`` (made once per test session, ~10 s)."""
    from dome_calib.bundle_io import write_bundle
    from dome_calib.recon.people.commands import people_options, reconstruct_folder
    from dome_calib.synth.dome import as_built_dome
    from dome_calib.synth.group_session import GroupSessionOptions, make_group_session
    from dome_calib.synth.skeleton import synthetic_sync

    root = tmp_path_factory.getbasetemp() / "skeletons_demo_group"
    if (root / "people").is_dir():
        return root
    root.mkdir()
    bundle = as_built_dome("tiny", seed=0)
    bundle.sync = synthetic_sync(bundle, start_ms=0.0, duration_ms=3000.0, seed=0)
    write_bundle(bundle, root / "bundle")
    make_group_session(root / "session", bundle, GroupSessionOptions(group=GroupOptions(
        n_people=7, start_ms=500.0, duration_ms=2000.0, seed=0)))
    reconstruct_folder(root / "session" / "detections", root / "bundle", root / "people.tmp", body_model="BODY_25",
                       options=people_options())
    (root / "people.tmp").rename(root / "people")
    return root


def people_page_data(page: Path) -> dict:
    """The data a people page shows (its JSON element, as the template's script reads it)."""
    html = page.read_text(encoding="utf-8")
    mark = '<script id="people-data" type="application/json">'
    start = html.index(mark) + len(mark)
    return json.loads(html[start:html.index("</script>", start)])
