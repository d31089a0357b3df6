"""Lens-model selection (dome_calib.ba.lens_model): per camera, only the lens terms the observations support.

Known truth: a synthetic ring of cameras whose points fill every image and whose prior lens is off like a design
value (every term determined or needed: all nine freed and recovered); the same ring seeing only the middle of
its images with the prior lens exact (k3 is neither determined over the image nor needed: held, so the corners
stay right); real photographs, one view each (tests/data/real_crop, the Strecha Herz-Jesu reference cameras): the
principal point and k3 are held, and the focal lengths come out far better than with everything free.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dome_calib.ba import BAOptions, BAProblem, bundle_adjust
from dome_calib.ba.lens_model import (LENS_TERMS, QUANTUM, GroupDecision, LensModelOptions, _decide, field_sigma_px,
                                      image_jacobian, wald_chi2)
from dome_calib.ba.problem import ParamGroup
from dome_calib.ba.quadratic import QuadraticModel
from dome_calib.bundle import Bundle, Camera, CameraType
from dome_calib.bundle_io import write_bundle
from dome_calib.camera import intr_to_K, pixels_to_normalized, project
from dome_calib.compare import compare_cameras, distortion_difference_px
from dome_calib.pipeline.stages import run_ba_stage
from dome_calib.rotation import rotvec_to_matrix

REAL_CROP = Path(__file__).parent / "data" / "real_crop"
TRUE_LENS = dict(intr=np.array([745.0, 748.0, 322.0, 236.0]), dist=np.array([-0.30, 0.12, 8e-4, -6e-4, 0.05]))


# ------------------------------------------------------------------------------------------ unit level
@settings(max_examples=25, deadline=None)
@given(k1=st.floats(-0.35, 0.1), k2=st.floats(-0.1, 0.2), p=st.floats(-1e-3, 1e-3), k3=st.floats(-0.1, 0.1),
       f=st.floats(400.0, 1500.0), dc=st.floats(-20.0, 20.0))
def test_image_jacobian_matches_finite_differences(k1, k2, p, k3, f, dc):
    """d pixel / d lens term at fixed rays, against central differences of the OpenCV projection (1e-6 px)."""
    params = np.zeros(15)
    params[6:10] = [f, 1.01 * f, 319.5 + dc, 239.5 - dc]
    params[10:15] = [k1, k2, p, -p, k3]
    J = image_jacobian(params, (640, 480), (5, 4))
    w, h = 640, 480
    u, v = np.meshgrid(np.linspace(0, w - 1, 5), np.linspace(0, h - 1, 4))
    xn = pixels_to_normalized(np.stack([u.ravel(), v.ravel()], -1), params[6:10], params[10:15])
    xn = xn[np.all(np.isfinite(xn), axis=1)]
    X = np.concatenate([xn, np.ones((len(xn), 1))], axis=1)  # rays at depth 1, camera at the origin
    for j in range(9):
        eps = 1e-6 * max(1.0, abs(params[6 + j]))
        hi, lo = params.copy(), params.copy()
        hi[6 + j] += eps
        lo[6 + j] -= eps
        num = (project(X, np.eye(3), np.zeros(3), hi[6:10], hi[10:15]).uv_px
               - project(X, np.eye(3), np.zeros(3), lo[6:10], lo[10:15]).uv_px) / (2 * eps)
        assert np.abs(num - J[:, :, j]).max() < 1e-6 * max(1.0, np.abs(J[:, :, j]).max()), LENS_TERMS[j]


def test_field_sigma_and_wald_of_one_term_and_of_independent_pairs():
    """One term: sigma field = sigma * max |J|, Wald = (delta / sigma)^2; two independent terms add up; two
    perfectly anti-correlated terms with opposite image effects leave no field uncertainty."""
    J = np.zeros((3, 2, 1))
    J[:, 0, 0] = [0.5, -2.0, 1.0]
    assert field_sigma_px(np.array([[0.25 ** 2]]), J) == pytest.approx(0.5, abs=1e-12)
    assert wald_chi2(np.array([[0.25 ** 2]]), np.array([0.75])) == pytest.approx(9.0, abs=1e-12)
    J2 = np.zeros((1, 2, 2))
    J2[0, 0, 0] = J2[0, 1, 1] = 1.0  # cx, cy
    assert field_sigma_px(np.diag([4.0, 1.0]), J2) == pytest.approx(2.0)
    assert wald_chi2(np.diag([4.0, 1.0]), np.array([2.0, 1.0])) == pytest.approx(2.0)
    Jc = np.ones((1, 2, 2))
    assert field_sigma_px(np.array([[1.0, -1.0], [-1.0, 1.0]]), Jc) == pytest.approx(0.0, abs=1e-7)


def test_quadratic_model_at_an_optimum_matches_the_bundle_adjustment():
    """At the solution of a problem, the quadratic model over the same free parameters takes no step, predicts
    the solver's own noise sigma and gives the covariance its uncertainty module reports (1e-6 relative)."""
    problem, _ = _ring_problem(prior_off=False, inner_fraction=1.0, n_points=800)
    result = bundle_adjust(problem, BAOptions(function_tolerance=1e-12, parameter_tolerance=1e-14))
    model = QuadraticModel.at(result, problem.free)
    lens = {i: list(range(6, 15)) for i in range(problem.n_cameras)}
    step, blocks = model.step(problem.free, lens)
    assert np.abs(step[:, 6:10]).max() < 1e-4 and np.abs(step[:, 10:]).max() < 1e-6  # px, unitless
    assert model.noise_px == pytest.approx(result.sigma_px, rel=1e-6)
    u = result.uncertainty
    for i in range(problem.n_cameras):
        sigma = np.sqrt(np.diag(blocks[i])) * model.noise_px
        assert sigma[:4] == pytest.approx(u.sigma_intr_px[i], rel=1e-6)
        assert sigma[4:] == pytest.approx(u.sigma_dist[i], rel=1e-6)


def test_quadratic_model_reuses_a_factor_only_for_the_same_parameters_and_damping():
    """A step over the same parameters with the same damping as the step before reuses its factorisation and
    gives what a fresh model gives, bit for bit; other parameters or another damping factorise again."""
    problem, _ = _ring_problem(prior_off=True, inner_fraction=1.0, n_points=400)
    result = bundle_adjust(problem, BAOptions(compute_uncertainty=False))
    lens = {i: [8, 9] for i in range(problem.n_cameras)}
    fresh = QuadraticModel.at(result, problem.free)
    model = QuadraticModel.at(result, problem.free)
    model.step(problem.free, lens)  # the principal points judged
    kept = model._factor
    step, blocks = model.step(problem.free, {i: [10, 11, 14] for i in range(problem.n_cameras)})  # then k1, k2, k3
    assert model._factor is kept
    ref_step, ref_blocks = fresh.step(problem.free, {i: [10, 11, 14] for i in range(problem.n_cameras)})
    assert np.array_equal(step, ref_step)
    assert all(np.array_equal(blocks[i], ref_blocks[i]) for i in ref_blocks)
    held = problem.free.copy()
    held[0, 8:10] = False  # the first camera's principal point held: another matrix
    other, _ = model.step(held)
    assert model._factor is not kept and other[0, 8:10].tolist() == [0.0, 0.0]
    kept = model._factor
    model.step(held, damping=1e-4)  # the same parameters, damped: another matrix
    assert model._factor is not kept


def test_decisions_compare_quantised_values():
    """A term within half a quantum of the limit counts as at the limit: the same verdict on every machine."""
    o = LensModelOptions()
    at_limit = _decide("k3", ("k3",), o.max_sigma_px + 0.4 * QUANTUM, 0.0, 7.0, o)
    assert at_limit.free and at_limit.reason.startswith("determined")
    above = _decide("k3", ("k3",), o.max_sigma_px + 2 * QUANTUM, 7.0 - 2 * QUANTUM, 7.0, o)
    assert not above.free and above.reason.startswith("held at the prior")
    needed = _decide("k3", ("k3",), 3.0, 7.0 - 0.4 * QUANTUM, 7.0, o)
    assert needed.free and needed.reason.startswith("needed")
    pp = _decide("principal_point", ("cx", "cy"), 4.9, 0.0, 14.0, o)  # the principal point's wider limit (5 px)
    assert pp.free


# ------------------------------------------------------------------------------------------ synthetic ring
def _ring_problem(*, prior_off: bool, inner_fraction: float, seed: int = 0, n_points: int = 3000,
                  noise_px: float = 0.15) -> tuple[BAProblem, dict[str, Camera]]:
    """12 VGA cameras around a ring (two heights, rolls -50..50 deg), 300 cm from the origin, looking at it;
    points in a 3 m cube that fills their images (``inner_fraction`` < 1: only observations within that fraction
    of the half-diagonal of an image are kept). Start: poses off by 1 cm / 0.2 deg, points by 1 cm; lens = the
    truth (``prior_off`` False) or off like a design value: 2 % focal, 4 px principal point, another distortion
    (1 to 3 px over the image per term)."""
    rng = np.random.default_rng(seed)
    truth = {}
    for k, yaw in enumerate(np.radians(np.arange(12) * 30.0)):
        centre = 300.0 * np.array([np.sin(yaw), 0.3 * (-1) ** k, -np.cos(yaw)])
        z = -centre / np.linalg.norm(centre)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        roll = np.radians(25.0 * (k % 5 - 2))
        R = rotvec_to_matrix(roll * np.array([0.0, 0.0, 1.0])) @ np.stack([x, np.cross(z, x), z])
        truth[f"01_{k + 1:02d}"] = Camera(name=f"01_{k + 1:02d}", type=CameraType.VGA, resolution=(640, 480),
                                          K=intr_to_K(TRUE_LENS["intr"]), dist=TRUE_LENS["dist"].copy(), R=R,
                                          t_cm=-R @ centre, panel=1, node=k + 1)
    X = rng.uniform(-150.0, 150.0, size=(n_points, 3))
    names = sorted(truth)
    proj = project(X, np.stack([truth[n].R for n in names]), np.stack([truth[n].t_cm for n in names]),
                   np.stack([truth[n].intr for n in names]), np.stack([truth[n].dist for n in names]))
    seen = proj.in_image(np.array([truth[n].resolution for n in names]))
    centre_px = np.array([319.5, 239.5])
    seen &= np.linalg.norm(proj.uv_px - centre_px, axis=-1) <= inner_fraction * np.linalg.norm(centre_px)
    keep = seen.sum(axis=0) >= 2
    X, seen, uv = X[keep], seen[:, keep], proj.uv_px[:, keep]
    ci, pi = np.nonzero(seen)
    uv_obs = uv[ci, pi] + rng.normal(0.0, noise_px, (len(ci), 2))
    start = {}
    for n, c in truth.items():
        R = rotvec_to_matrix(np.radians(0.2) * rng.normal(size=3) / np.sqrt(3)) @ c.R
        centre = c.center_cm + rng.normal(0.0, 1.0, 3)
        K, dist = c.K.copy(), c.dist.copy()
        if prior_off:
            K[0, 0] *= 1.02
            K[1, 1] *= 1.02
            K[:2, 2] += [4.0, -4.0]
            dist = dist + np.array([0.03, -0.04, 1.5e-3, 1.5e-3, 0.15])
        start[n] = replace(c, R=R, t_cm=-R @ centre, K=K, dist=dist)
    problem = BAProblem.from_cameras(start, {"scene_01": X + rng.normal(0.0, 1.0, X.shape)}, camera_index=ci,
                                     point_index=pi, uv_px=uv_obs, camera_names=names)
    return problem, truth


def test_well_observed_cameras_keep_every_lens_term_free():
    problem, truth = _ring_problem(prior_off=True, inner_fraction=1.0)
    outcome = run_ba_stage(problem)
    lens = outcome.lens_model["cameras"]
    assert all(lens[n]["free"] == list(LENS_TERMS) and lens[n]["held"] == [] for n in truth), lens
    for n, cam in outcome.cameras.items():  # recovered: the prior was off by 2 %, 4 px and another lens
        assert np.abs(cam.intr[:2] / truth[n].intr[:2] - 1.0).max() < 2e-3  # 0.2 %
        pp_sigma_px = next(d["sigma_px"] for d in lens[n]["decisions"] if d["group"] == "principal_point")
        # within 3 sigma, px (sigma at the 0.2 px noise floor; the ring's noise is 0.15 px)
        assert np.linalg.norm(cam.intr[2:] - truth[n].intr[2:]) < 3.0 * pp_sigma_px < 2.7
        assert distortion_difference_px(cam, truth[n]) < 1.0  # px over the whole image
    assert {d["group"] for d in lens["01_01"]["decisions"]} == {"principal_point", "k3", "tangential", "k2", "k1"}
    tangential = next(d for d in lens["01_01"]["decisions"] if d["group"] == "tangential")
    assert "principal point" in tangential["reason"]  # decentering is only held together with the principal point
    assert outcome.lens_model["solves"] == 2  # the smallest model, then the chosen one (confirmed, not re-solved)


def test_image_centre_only_holds_k3_at_an_exact_prior():
    """Seen only within half of the image radius, k3 moves the corners by several px per sigma and the fit
    does not need it: held at the prior (here exact), so the corners stay right."""
    problem, truth = _ring_problem(prior_off=False, inner_fraction=0.5)
    outcome = run_ba_stage(problem)
    lens = outcome.lens_model["cameras"]
    for n in truth:
        assert "k3" in lens[n]["held"] and "fx" in lens[n]["free"], lens[n]
        k3 = next(d for d in lens[n]["decisions"] if d["group"] == "k3")
        assert k3["sigma_px"] > 0.5 and k3["wald_chi2"] < k3["penalty_chi2"]
        assert outcome.problem.camera(n).dist[4] == problem.camera(n).dist[4]  # bit-identical prior value
        assert distortion_difference_px(outcome.cameras[n], truth[n]) < 1.0
    everything_free = bundle_adjust(problem, BAOptions(compute_uncertainty=False))
    worst_free = max(distortion_difference_px(everything_free.problem.camera(n), truth[n]) for n in truth)
    worst_chosen = max(distortion_difference_px(outcome.cameras[n], truth[n]) for n in truth)
    assert worst_chosen < worst_free  # extrapolating a free k3 to the corners is what the selection avoids


@pytest.mark.parametrize("settled_fraction, solves", [(0.05, 2), (0.0, 3)])
def test_a_pass_flipping_few_terms_keeps_the_solved_choice(monkeypatch, settled_fraction, solves):
    """A second pass that would flip one term (of the ring's judged lens terms) ends the selection at 5 % (the
    solved choice and its own decisions are returned), and is solved again at 0."""
    import dome_calib.ba.lens_model as lens_model_module
    from dome_calib.ba.lens_model import select_lens_model, warm_solver
    from dome_calib.ba.problem import CAMERA_PARAMS

    problem, _ = _ring_problem(prior_off=True, inner_fraction=1.0, n_points=600)
    K3 = CAMERA_PARAMS.index("k3")
    walks: list[bool] = []  # camera 0's k3 free, per pass
    real_walk = lens_model_module._walk

    def walk(*args, **kwargs):
        free, decisions = real_walk(*args, **kwargs)
        if len(walks) == 1:  # the second pass flips camera 0's k3
            free = free.copy()
            free[0, K3] = not free[0, K3]
        walks.append(bool(free[0, K3]))
        return free, decisions

    monkeypatch.setattr(lens_model_module, "_walk", walk)
    options = LensModelOptions(settled_fraction=settled_fraction)
    result, lens = select_lens_model(problem, warm_solver(BAOptions(compute_uncertainty=False)), options)
    assert lens.solves == solves if solves == 2 else lens.solves >= solves
    for i, name in enumerate(problem.camera_names):  # what is reported is what was solved
        solved = [t for t in LENS_TERMS if result.problem.free[i, CAMERA_PARAMS.index(t)]]
        assert lens.cameras[name].free == solved
    if solves == 2:  # settled: the first pass's choice, not the flip
        assert result.problem.free[0, K3] == walks[0] != walks[1]


def test_without_uncertainties_the_stage_keeps_the_callers_mask():
    """The quick path's solver options (no covariance): one solve, the given free mask, no lens model."""
    problem, _ = _ring_problem(prior_off=False, inner_fraction=0.5, n_points=600)
    problem.fix("k3", "01_02")
    outcome = run_ba_stage(problem, options=BAOptions(compute_uncertainty=False))
    assert outcome.lens_model is None and outcome.stats["solves"] == 1
    assert np.array_equal(outcome.problem.free, problem.free)


# ------------------------------------------------------------------------------------------ real photographs
def _strecha_cameras(scale: float, cm_per_m: float = 25.0) -> dict[str, Camera]:
    """Reference cameras of tests/data/real_crop for images ``scale`` times the full 3072 x 2048 size, in a
    dome-sized frame (centroid at the origin, cm_per_m cm per survey metre, R re-orthonormalised)."""
    raw = {}
    for i, path in enumerate(sorted(REAL_CROP.glob("*.camera"))):
        rows = [[float(v) for v in line.split()] for line in path.read_text().splitlines() if line.strip()]
        raw[f"00_{i:02d}"] = (np.array(rows[0:3]), np.array(rows[4:7]), np.array(rows[7]), rows[8])
    centroid = np.mean([c for _, _, c, _ in raw.values()], axis=0)
    cams = {}
    for name, (K, R_wfc, C, size) in raw.items():
        U, _, Vt = np.linalg.svd(R_wfc.T)
        R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        intr = np.array([K[0, 0] * scale, K[1, 1] * scale, (K[0, 2] + 0.5) * scale - 0.5,
                         (K[1, 2] + 0.5) * scale - 0.5])
        cams[name] = Camera(name=name, type=CameraType.HD, resolution=(round(size[0] * scale), round(size[1] * scale)),
                            K=intr_to_K(intr), dist=np.zeros(5), R=R, t_cm=-R @ ((C - centroid) * cm_per_m), panel=0,
                            node=int(name[3:]) + 1)
    return cams


@pytest.fixture(scope="module")
def real_crop(tmp_path_factory):
    """A one-scene capture of 4 real photographs (768 x 512) and a prior perturbed like an old calibration
    (centres 0.5 cm, rotations 1 deg, focal +3 %; centres within the world-frame fit's 1 cm inlier threshold),
    calibrated with `calibrate --prior`."""
    from dome_calib.pipeline.full import run_calibration
    from dome_calib.pipeline.types import CalibrateOptions

    from .report_data import NO_PLOTS

    root = tmp_path_factory.mktemp("real_crop")
    reference = _strecha_cameras(0.25)
    capture = root / "capture"
    (capture / "scenes" / "scene_01").mkdir(parents=True)
    for name, jpg in zip(sorted(reference), sorted(REAL_CROP.glob("*.jpg"))):
        cv2.imwrite(str(capture / "scenes" / "scene_01" / f"{name}.png"), cv2.imread(str(jpg), cv2.IMREAD_GRAYSCALE))
    (capture / "capture.json").write_text(json.dumps({"scenes": ["scene_01"], "cameras": sorted(reference)}))
    rng = np.random.default_rng(0)
    prior = {}
    for n, c in sorted(reference.items()):
        d, a = rng.normal(size=3), rng.normal(size=3)
        R = rotvec_to_matrix(np.radians(1.0) * a / np.linalg.norm(a)) @ c.R
        K = c.K.copy()
        K[0, 0] *= 1.03
        K[1, 1] *= 1.03
        prior[n] = replace(c, R=R, t_cm=-R @ (c.center_cm + 0.5 * d / np.linalg.norm(d)), K=K)
    write_bundle(Bundle(seq="prior", cameras=prior), root / "prior")
    result = run_calibration(capture, root / "out", CalibrateOptions(prior=root / "prior", work_dir=root / "work",
                                                                report=NO_PLOTS))  # reads no plot
    return result, reference, root / "out"


def test_real_one_view_cameras_hold_what_they_cannot_determine(real_crop):
    result, reference, out = real_crop
    assert sorted(result.bundle.cameras) == sorted(reference)
    lens = result.ba.lens_model["cameras"]
    for n in reference:
        assert {"cx", "cy", "k3"} <= set(lens[n]["held"]) and {"fx", "fy"} <= set(lens[n]["free"]), lens[n]
        pp = next(d for d in lens[n]["decisions"] if d["group"] == "principal_point")
        assert pp["sigma_px"] > 5.0 and not pp["free"]  # one view: the principal point is open by > 5 px
    chosen = compare_cameras(result.bundle.cameras, reference).summary()["all"]
    assert chosen["focal_pct_max"] < 3.0 and chosen["principal_px_max"] == 0.0  # held at the prior (exact here)
    assert chosen["distortion_px_max"] < 1.5  # px over the whole image; the reference lens is distortion-free
    everything_free = bundle_adjust(result.sfm.problem, BAOptions(compute_uncertainty=False))
    free_cams = {n: everything_free.problem.camera(n) for n in everything_free.problem.camera_names}
    free_err = compare_cameras(free_cams, reference).summary()["all"]
    # what holding the undetermined terms buys on four one-view cameras. Everything free, the lens terms are
    # undetermined and where the solve ends along them depends on its path: converging every outlier round, focal
    # 15.4 %, principal point 41 px, centres 2.2 cm; one step per intermediate round, 7.0 %, 17 px, 0.79 cm
    # (chosen: 2.0 %, held, 0.46 cm either way); on the refined keypoints (projector.refine) everything free still
    # leaves the principal points 9.7 px off (median)
    assert free_err["focal_pct_median"] > 3 * chosen["focal_pct_median"]
    assert free_err["center_cm_median"] > 1.5 * chosen["center_cm_median"]
    assert free_err["principal_px_median"] > 5.0 and free_err["distortion_px_max"] > 5.0
    report = json.loads((out / "report" / "report.json").read_text())
    assert report["lens_model"]["cameras"]["00_00"]["held"] == lens["00_00"]["held"]
    assert report["per_camera"]["00_00"]["lens_held"] == lens["00_00"]["held"]
    assert "cx" not in report["per_camera"]["00_00"]["lens_free"]
    from dome_calib.report.command import report_bundle

    report_bundle(out)  # `dome-calib report` rewrites the report: the lens model, known only to calibrate, stays
    again = json.loads((out / "report" / "report.json").read_text())
    assert again["lens_model"] == report["lens_model"]
    assert again["per_camera"]["00_00"]["lens_held"] == lens["00_00"]["held"]


# ------------------------------------------------------------------------------------------ marginal, not conditional
def _facade_problem(*, depth_cm: float, seed: int = 0, n_points: int = 1500, noise_px: float = 0.25,
                    k1: float = 0.0) -> tuple[BAProblem, dict[str, Camera]]:
    """8 HD-like cameras (1536 x 1024, f 1380 px) along a 4 m path 6 m from a facade 6 x 4 m whose points lie
    within +-depth_cm/2 of a plane, each looking at it once (one view per camera, one scene); ``noise_px`` noise;
    the lens's radial ``k1`` (0: none). Start: rotations 1 deg off, centres 1 cm, focal +3 %, principal point
    exact, distortion zero."""
    rng = np.random.default_rng(seed)
    intr = np.array([1380.0, 1380.0, 767.5, 511.5])
    truth = {}
    for k in range(8):
        centre = np.array([-200.0 + 400.0 * k / 7, 0.0, -600.0 + 30.0 * rng.normal()])
        z = rng.normal(0.0, 20.0, 3) - centre
        z /= np.linalg.norm(z)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        truth[f"00_{k:02d}"] = Camera(name=f"00_{k:02d}", type=CameraType.HD, resolution=(1536, 1024),
                                      K=intr_to_K(intr), dist=np.array([k1, 0.0, 0.0, 0.0, 0.0]), R=R,
                                      t_cm=-R @ centre, panel=0, node=k + 1)
    X = np.stack([rng.uniform(-300, 300, n_points), rng.uniform(-200, 200, n_points),
                  rng.uniform(-depth_cm / 2, depth_cm / 2, n_points)], axis=1)
    names = sorted(truth)
    proj = project(X, np.stack([truth[n].R for n in names]), np.stack([truth[n].t_cm for n in names]),
                   np.stack([truth[n].intr for n in names]), np.stack([truth[n].dist for n in names]))
    seen = proj.in_image(np.array([truth[n].resolution for n in names]))
    keep = seen.sum(axis=0) >= 2
    X, seen, uv = X[keep], seen[:, keep], proj.uv_px[:, keep]
    ci, pi = np.nonzero(seen)
    start = {}
    for n, c in truth.items():
        R = rotvec_to_matrix(np.radians(1.0) * rng.normal(size=3) / np.sqrt(3)) @ c.R
        K = c.K.copy()
        K[0, 0] *= 1.03
        K[1, 1] *= 1.03
        start[n] = replace(c, R=R, t_cm=-R @ (c.center_cm + rng.normal(0.0, 1.0, 3)), K=K, dist=np.zeros(5))
    problem = BAProblem.from_cameras(start, {"scene_01": X + rng.normal(0.0, 1.0, X.shape)}, camera_index=ci,
                                     point_index=pi, uv_px=uv[ci, pi] + rng.normal(0.0, noise_px, (len(ci), 2)),
                                     camera_names=names)
    return problem, truth


def _principal_point_sigmas(problem: BAProblem) -> tuple[list[GroupDecision], np.ndarray, np.ndarray]:
    """The principal-point decisions of one walk at the focal-only solution, and per camera the marginal and the
    conditional 1-sigma (px, largest axis) computed here independently from the reduced normal matrix."""
    from dome_calib.ba.lens_model import _walk

    smallest = problem.copy()
    smallest.fix(ParamGroup.PRINCIPAL_POINT)
    smallest.fix(ParamGroup.DISTORTION)
    point = bundle_adjust(smallest, BAOptions(compute_uncertainty=False))
    model = QuadraticModel.at(point, problem.free)
    _, decisions = _walk(model, point, problem, problem.free.copy(), list(range(problem.n_cameras)),
                         LensModelOptions())
    cov = np.linalg.inv(model.S) * model.noise_px ** 2  # every free camera parameter; points eliminated
    marginal, conditional = [], []
    for i in range(problem.n_cameras):
        ix = model.index[i, [8, 9]]
        marginal.append(np.sqrt(np.linalg.eigvalsh(cov[np.ix_(ix, ix)])[-1]))
        conditional.append(np.sqrt(np.linalg.eigvalsh(np.linalg.inv(model.S[np.ix_(ix, ix)]))[-1]) * model.noise_px)
    pp = [next(d for d in decisions[n] if d.group == "principal_point") for n in problem.camera_names]
    return pp, np.array(marginal), np.array(conditional)


def test_one_view_of_a_shallow_scene_holds_the_principal_point_by_its_marginal_sigma():
    """One view per camera of a nearly flat facade: the principal point trades with rotation and focal length
    (a plane fixes only a homography, 8 numbers, against the 9 of pose, focal and principal point). Its own
    diagonal block (everything else held) says 0.01 px; its marginal (the block of the inverse, rotation, focal,
    the other cameras and the points free) says tens of px. The rule uses the marginal one and holds it."""
    problem, truth = _facade_problem(depth_cm=5.0)
    pp, marginal, conditional = _principal_point_sigmas(problem)
    sigma = np.array([d.sigma_px for d in pp])
    # what the rule judges is the marginal sigma: ~700-2,000 px here, a near-singular block's, known only to ~1 %
    # (one ulp in rotation.right_jacobian, safe ** 3 against safe * safe * safe, moved the walk's by up to 0.8 % and
    # this inverse's by up to 0.6 %, each its own way), against the rule's 10 px
    np.testing.assert_allclose(sigma, marginal, rtol=2e-2)
    assert conditional.max() < 0.05 < 5.0 < 10.0 < marginal.min()  # the conditional one would free it
    assert not any(d.free for d in pp), [d.reason for d in pp]
    outcome = run_ba_stage(problem)
    for n in truth:
        assert {"cx", "cy"} <= set(outcome.lens_model["cameras"][n]["held"])
        assert np.array_equal(outcome.cameras[n].intr[2:], problem.camera(n).intr[2:])  # the prior, bit for bit


def test_many_views_of_a_deep_scene_may_free_the_principal_point():
    """The ring: twelve cameras around a 3 m cube of points that fills their images. The principal point's
    marginal sigma is small (well under the 5 px limit, yet still several times its conditional one: the
    rotation trade-off is there but the depth and the other views resolve it) and it is freed."""
    problem, truth = _ring_problem(prior_off=True, inner_fraction=1.0, n_points=1500)
    pp, marginal, conditional = _principal_point_sigmas(problem)
    np.testing.assert_allclose([d.sigma_px for d in pp], marginal, rtol=1e-3)
    assert marginal.max() < 2.0 and (marginal > 1.5 * conditional).all()
    assert all(d.free for d in pp)


def _focal_covariance_pct(problem: BAProblem, inlier: np.ndarray, noise_px: float) -> np.ndarray:
    """(C, C) covariance (%^2) of the cameras' focal errors (mean of fx and fy, relative) that ``noise_px`` of
    pixel noise leaves at the solution ``problem`` (its free parameters estimated, the points eliminated), computed
    here from the Jacobians alone: the reduced camera matrix in numpy, the 7 gauge directions (to which a focal
    length is blind) dropped from its inverse."""
    from dome_calib.ba.evaluate import residuals_and_jacobians

    cam, pt = problem.camera_index[inlier], problem.point_index[inlier]
    _, Jc, Jp = residuals_and_jacobians(problem.camera_params, problem.points_cm, cam, pt, problem.uv_px[inlier])
    n = problem.n_cameras * 15
    A = np.zeros((len(cam), 2, n))  # d residual / d every camera parameter
    A[np.arange(len(cam))[:, None, None], np.arange(2)[None, :, None], (cam[:, None] * 15 + np.arange(15))[:, None, :]] \
        = Jc.transpose(2, 0, 1)
    B = Jp.transpose(2, 0, 1)  # (M, 2, 3)
    W = np.zeros((problem.n_points, n, 3))
    np.add.at(W, pt, np.einsum("mri,mrj->mij", A, B))
    V = np.zeros((problem.n_points, 3, 3))
    np.add.at(V, pt, np.einsum("mri,mrj->mij", B, B))
    S = np.einsum("mri,mrj->ij", A, A) - np.einsum("pia,pab,pjb->ij", W, np.linalg.pinv(V), W)
    free = np.flatnonzero(problem.free.ravel())
    S = S[np.ix_(free, free)]
    d = np.sqrt(np.diag(S))
    w, U = np.linalg.eigh(S / np.outer(d, d))
    cov = (U[:, 7:] / w[7:]) @ U[:, 7:].T / np.outer(d, d) * noise_px ** 2
    pos = {int(k): j for j, k in enumerate(free)}
    F = np.zeros((problem.n_cameras, len(free)))
    for i in range(problem.n_cameras):
        for c in (6, 7):
            F[i, pos[i * 15 + c]] = 50.0 / problem.camera_params[i, c]
    return F @ cov @ F.T


@pytest.mark.parametrize("k1", [0.0, pytest.param(-0.005, marks=pytest.mark.slow)])
def test_one_sign_focal_errors_on_a_shallow_scene_are_its_common_mode_not_a_bias(k1):
    """Issue 52: on a real facade every camera's focal length came out short. On a facade whose relief is 5 cm
    over 6 m, seen once per camera, the focal lengths are tied to the scene's depth and to each other through the
    shared points: the data leave the cameras' focal errors 50-80 % correlated, so one sign on every camera is
    what noise alone gives. Noise 0.07 px: the residual RMS on Herz-Jesu-P8 (bench/real.py, 0.068 px). The test:
    in each draw (prior focal +3 % every time) the mean focal error is within 3 sigma of what the data's own
    covariance predicts for it, and its sign is not the same in every draw (a bias would be); the principal point
    stays held (freed, its error multiplies the focal's). With a lens the prior does not know (k1 -0.005: 2 px at the
    corners, prior zero) the rule frees k1 and the same holds."""
    means, signs = [], set()
    for seed in range(4):
        problem, truth = _facade_problem(depth_cm=5.0, seed=seed, noise_px=0.07, k1=k1)
        outcome = run_ba_stage(problem)
        names = outcome.problem.camera_names
        assert all({"cx", "cy"} <= set(outcome.lens_model["cameras"][n]["held"]) for n in names)
        if k1:
            assert all("k1" in outcome.lens_model["cameras"][n]["free"] for n in names)
        err = np.array([100.0 * (np.mean(outcome.cameras[n].intr[:2] / truth[n].intr[:2]) - 1.0) for n in names])
        cov = _focal_covariance_pct(outcome.problem, outcome.inlier, noise_px=0.07)
        sd = np.sqrt(np.diag(cov))
        assert (cov / np.outer(sd, sd)).mean() > 0.4  # the common mode: strongly correlated focal errors
        assert abs(err.mean()) < 3.0 * np.sqrt(cov.mean()), (seed, err.round(3), np.sqrt(cov.mean()))
        means.append(err.mean())
        signs.add(bool(err.mean() > 0))
    assert signs == {True, False}, np.round(means, 3)  # the prior is 3 % long every time: no pull toward it
