"""How a 2D pose detector errs, measured against a 3D reference: the statistics the synthetic detector
(:mod:`dome_calib.synth.detector`) is fitted to, measured the same way on real OpenPose output and on its own.

A :class:`Track` is one person seen by V views over F frames of one frame period: the detections, the reference
projections they are judged against (a robust 3D fit reprojected, or the truth), the person's height in each view
(``h_px = fy * 170 cm * scale / depth``, the detector model's own measure of size; ``scale`` from the bone
lengths), which joints a body hides (:mod:`dome_calib.synth.body_volume`) and, for a fitted reference, each
observation's leverage in the fit. :func:`measure` turns it into the statistics:

- ``noise``: per joint type, the residual ``(detection - reference) / h_px`` per coordinate of the joints no body
  hides (hidden ones: their ratio to it), each residual of an
  observation that was in the fit divided by ``sqrt(1 - leverage)`` (a fitted point follows its own
  observations; this undoes it), sigma as ``median |r| / 1.1774`` (the median of a 2D Gaussian's norm); the
  distribution of the inliers (``|z| < k_outlier``) against a Gaussian's quantiles and kurtosis;
- ``noise_time``: the autocorrelation of the visible inliers' residuals over lags (ms), split into a constant part per
  (view, joint) over the track (``bias_share``), an exponentially correlated part (``tau_ms``) and a white part;
- ``outliers``: joints no body hides more than ``k_outlier`` sigmas off: rates per joint class, episodes (runs
  of frames above ``k_outlier`` continued while above ``k_continue``), their durations (frames and ms) and
  sizes (the largest ``|r| / h_px`` of each episode; every frame's in ``size_rel_frames_quantiles``);
- ``misses``: joints not detected (c = 0), visible and hidden apart, with their run lengths;
- ``swaps``: left/right pairs whose detections fit the mirrored reference better (half the error or less),
  among the pairs whose two joints are apart by more than 5 % of the height, with run lengths; a person-image
  with a swapped pair is left out of every other figure;
- ``confidence``: quantiles for visible inliers, hidden inliers and outliers; values above 1; autocorrelation;
- ``quirks``: a coordinate written as exactly 0 with a confidence above 0.

Run lengths count frames; ``*_ms`` multiply them by the frame period. Lognormal fits (``median``, ``log_sd``)
are of the values as measured (a run of L frames taken as L frame periods).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from dome_calib.arrays import per_row
from dome_calib.recon.body_models import JOINTS19
from dome_calib.synth.detector_model import CONF_PERCENTILES, Lognormal

#: The joint classes whose outlier and miss rates are told apart (joints19 indices).
JOINT_CLASSES = {"wrists": [5, 11], "limbs": [3, 4, 6, 7, 8, 9, 10, 12, 13, 14], "face": [1, 15, 16, 17, 18]}
#: Left/right pairs judged for swaps (shoulders, elbows, wrists, hips, knees, ankles, eyes, ears).
LR_PAIRS = [(3, 9), (4, 10), (5, 11), (6, 12), (7, 13), (8, 14), (15, 17), (16, 18)]
#: median |r| of a 2D standard normal: sigma = median |r| / this.
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))
ACF_LAGS_MS = (16.7, 33.3, 50.0, 66.7, 100.0, 133.3, 200.0, 266.7, 400.0)


@dataclass(kw_only=True)
class Track:
    """One person seen by V views at F frames, ``frame_ms`` apart.

    kp (F, V, 19, 3) detections [x_px, y_px, c] (c = 0: missed); uv_ref_px (F, V, 19, 2) the reference's
    projections; h_px (F, V) person height; hidden (F, V, 19) bool; leverage (F, V, 19) in [0, 1) (0: not in the
    fit, or a truth reference); joints: the joints19 indices measured (the detector's own joints, not derived ones).
    """

    kp: np.ndarray
    uv_ref_px: np.ndarray
    h_px: np.ndarray
    hidden: np.ndarray
    leverage: np.ndarray
    frame_ms: float
    joints: tuple[int, ...] = tuple(j for j in range(19) if JOINTS19[j] not in ("neck", "body_center"))


def run_lengths(on: np.ndarray) -> np.ndarray:
    """Lengths of the runs of True along axis 0 of a (F, ...) bool array, every column apart (order: column-major
    over the trailing axes, then time)."""
    b = per_row(np.asarray(on, dtype=bool)).T  # (columns, F)
    pad = np.zeros((len(b), 1), dtype=bool)
    d = np.diff(np.concatenate([pad, b, pad], axis=1).astype(np.int8), axis=1)
    starts, ends = np.nonzero(d == 1), np.nonzero(d == -1)
    return (ends[1] - starts[1]).astype(np.int64)


def hysteresis_runs(high: np.ndarray, low: np.ndarray, value: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                    np.ndarray]:
    """Runs along axis 0 of ``low`` (F, ...) that contain at least one ``high`` frame: (their lengths, a mask of
    their frames shaped like ``low``, the largest ``value`` of each run)."""
    F = len(low)
    lo = np.asarray(low, bool).reshape(F, -1).T
    hi = np.asarray(high, bool).reshape(F, -1).T & lo
    val = np.asarray(value, dtype=float).reshape(F, -1).T
    pad = np.zeros((len(lo), 1), dtype=bool)
    d = np.diff(np.concatenate([pad, lo, pad], axis=1).astype(np.int8), axis=1)
    (sc, s), (_, e) = np.nonzero(d == 1), np.nonzero(d == -1)
    csum = np.concatenate([np.zeros((len(hi), 1), np.int64), np.cumsum(hi, axis=1)], axis=1)
    keep = csum[sc, e] - csum[sc, s] > 0
    mask = np.zeros_like(lo)
    peaks = []
    for c, a, b in zip(sc[keep], s[keep], e[keep]):
        mask[c, a:b] = True
        peaks.append(float(np.max(val[c, a:b])))
    return (e - s)[keep].astype(np.int64), mask.T.reshape(np.shape(low)), np.array(peaks)


def lognormal_fit(values: np.ndarray) -> dict:
    """``{"n", "median", "log_sd", "mean"}`` of positive values (NaN when fewer than 2)."""
    v = np.asarray(values, dtype=float)
    v = v[v > 0]
    if len(v) < 2:
        return {"n": int(len(v)), "median": float("nan"), "log_sd": float("nan"), "mean": float(np.mean(v)) if len(v)
                else float("nan")}
    lv = np.log(v)
    return {"n": int(len(v)), "median": float(np.exp(lv.mean())), "log_sd": float(lv.std(ddof=1)),
            "mean": float(v.mean())}


def _q(values: np.ndarray, qs=(5, 25, 50, 75, 95)) -> dict:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return {f"q{q}": (round(float(np.percentile(v, q)), 4) if len(v) else None) for q in qs}


def _centred(a: np.ndarray) -> np.ndarray:
    """(F, ...) values (NaN = none) less each column's mean over axis 0 (columns with none stay NaN)."""
    n = np.sum(np.isfinite(a), axis=0, keepdims=True)
    return a - np.nansum(a, axis=0, keepdims=True) / np.maximum(n, 1)


def _acf(res: np.ndarray, lags_frames: list[int]) -> list[float]:
    """Autocorrelation of (F, ...) residuals (NaN = none) at the lags, pooled over the trailing axes."""
    out = []
    for lag in lags_frames:
        a, b = res[:-lag], res[lag:]
        ok = np.isfinite(a) & np.isfinite(b)
        num = np.sum(np.where(ok, a * b, 0.0))
        den = np.sqrt(np.sum(np.where(ok, a * a, 0.0)) * np.sum(np.where(ok, b * b, 0.0)))
        out.append(float(num / den) if den > 0 else float("nan"))
    return out


def _expected_acf(tau_ms: float, white: float, bias: float, lags: np.ndarray, n_frames: int, frame_ms: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The autocorrelations :func:`_acf` expects, raw and with the track's mean removed, of a unit-variance process
    ``bias`` (constant over the track) + exponentially correlated (tau) + ``white``, over ``n_frames`` frames."""
    i = np.arange(n_frames)
    ou = max(1.0 - white - bias, 0.0)
    C = ou * np.exp(-np.abs(i[:, None] - i[None]) * frame_ms / tau_ms) + white * np.eye(n_frames)
    Hc = C - C.mean(0, keepdims=True) - C.mean(1, keepdims=True) + C.mean()  # H C H, H = I - 1 1^T / F
    centred = np.array([np.mean(np.diagonal(Hc, int(lag))) for lag in lags]) / np.mean(np.diagonal(Hc))
    raw = bias + ou * np.exp(-lags * frame_ms / tau_ms)
    return raw, centred


def _fit_time(acf_raw: list[float], acf_centred: list[float], lags_frames: list[int], n_frames: int,
              frame_ms: float) -> dict:
    """Split a residual's variance into bias (constant per view and joint over the track), an exponentially
    correlated part (``tau_ms``) and white noise: least squares of both measured autocorrelations against what a
    track of this length gives (:func:`_expected_acf`; removing the track's mean pulls the centred one down)."""
    raw, cen = np.asarray(acf_raw, dtype=float), np.asarray(acf_centred, dtype=float)
    lags = np.asarray(lags_frames, dtype=float)
    ok = np.isfinite(raw) & np.isfinite(cen)
    if ok.sum() < 3:
        return {"tau_ms": float("nan"), "white_share": float("nan"), "bias_share": float("nan")}

    def cost(p: np.ndarray) -> np.ndarray:
        e_raw, e_cen = _expected_acf(p[0], p[1], p[2], lags[ok], n_frames, frame_ms)
        return np.concatenate([e_raw - raw[ok], e_cen - cen[ok], [10.0 * max(p[1] + p[2] - 1.0, 0.0)]])

    grid = [(t, w, b) for t in (25.0, 50.0, 100.0, 200.0, 400.0) for w in (0.0, 0.1) for b in (0.0, 0.2, 0.5)]
    start = min(grid, key=lambda p: float(np.sum(cost(np.array(p)) ** 2)))
    fit = least_squares(cost, np.array(start), bounds=([1.0, 0.0, 0.0], [5000.0, 1.0, 1.0]), x_scale=[50.0, 0.1, 0.1])
    tau, white, bias = fit.x
    return {"tau_ms": round(float(tau), 1), "white_share": round(float(white), 3), "bias_share": round(float(bias), 3)}


def measure(track: Track, *, k_outlier: float = 5.0, k_continue: float = 3.0) -> dict[str, dict]:
    """The detector's statistics on one track (see the module docstring); one dict per section, JSON-ready."""
    t = track
    F, V = t.kp.shape[:2]
    J = np.array(t.joints)
    swapped = _swapped_pairs(t, t.kp[..., 2] > 0)
    plain = ~swapped.any(-1)  # (F, V) person-images without a left/right swap: every other figure is theirs
    det = (t.kp[..., 2] > 0) & plain[..., None]
    quirk = det & ((t.kp[..., 0] == 0) | (t.kp[..., 1] == 0))
    use = det & ~quirk
    r = (t.kp[..., :2] - t.uv_ref_px) / t.h_px[..., None, None]
    r = r / np.sqrt(1.0 - np.clip(t.leverage, 0.0, 0.95))[..., None]
    e = np.linalg.norm(r, axis=-1)
    seen = use & ~t.hidden  # sigma: of the joints no body hides (the hidden ones' is a ratio to it)
    sigma = np.array([np.median(e[..., j][seen[..., j]]) / RAYLEIGH_MEDIAN if seen[..., j].sum() > 10 else np.nan
                      for j in range(19)])
    z = e / sigma
    out_hi, out_lo = seen & (z > k_outlier), seen & (z > k_continue)  # outliers: of the joints no body hides
    lengths, in_episode, peaks = hysteresis_runs(out_hi[..., J], out_lo[..., J], e[..., J])
    outlier = np.zeros_like(use)
    outlier[..., J] = in_episode
    inlier = use & ~outlier
    vis, hid = ~t.hidden & plain[..., None], t.hidden & plain[..., None]
    sections: dict[str, dict] = {}
    core = (r / sigma[:, None])[..., J, :][inlier[..., J] & vis[..., J]]
    core = core.ravel()
    sections["noise"] = {
        "n": int(inlier[..., J].sum()),
        "sigma_rel_per_joint": {JOINTS19[j]: round(float(sigma[j]), 5) for j in J},
        "sigma_rel_median": round(float(np.median(sigma[J])), 5),
        "sigma_rel_hidden_over_visible": round(float(np.median(e[..., J][inlier[..., J] & hid[..., J]]) /
                                                     np.median(e[..., J][inlier[..., J] & vis[..., J]])), 3)
        if (inlier[..., J] & hid[..., J]).sum() > 20 else None,
        "core_std": round(float(core.std()), 3),
        "core_kurtosis": round(float(np.mean((core - core.mean()) ** 4) / core.var() ** 2), 3),
        "core_abs_quantiles": {f"q{q}": round(float(np.percentile(np.abs(core), q)), 3) for q in (50, 90, 99)},
        "gaussian_abs_quantiles": {"q50": 0.674, "q90": 1.645, "q99": 2.576},
        "h_px_median": round(float(np.median(t.h_px)), 1),
        "leverage_mean_in_fit": round(float(np.mean(t.leverage[t.leverage > 0])), 3) if np.any(t.leverage > 0)
        else 0.0,
    }
    lags_frames = sorted({max(1, int(round(ms / t.frame_ms))) for ms in ACF_LAGS_MS if ms / t.frame_ms < F / 3})
    zi = np.where((inlier & vis)[..., None], r / sigma[:, None], np.nan)[:, :, J]  # (F, V, J, 2)
    centred = _centred(zi)
    acf_raw, acf_c = _acf(zi, lags_frames), _acf(centred, lags_frames)
    lags_ms = np.array(lags_frames) * t.frame_ms
    sections["noise_time"] = {"lags_ms": [round(float(x), 1) for x in lags_ms],
                              "acf": [round(a, 3) for a in acf_raw], "acf_track_mean_removed": [round(a, 3) for a in
                                                                                              acf_c],
                              **_fit_time(acf_raw, acf_c, lags_frames, F, t.frame_ms)}
    n_use = seen[..., J].sum()
    sizes = e[..., J][in_episode]
    sections["outliers"] = {
        "k_outlier": k_outlier, "k_continue": k_continue,
        "rate_by_k": {str(k): round(float((seen[..., J] & (z[..., J] > k)).sum() / n_use), 5) for k in (3, 4, 5, 8)},
        "rate": round(float(in_episode.sum() / n_use), 5),
        "rate_by_class": {c: round(float(outlier[..., js].sum() / max(seen[..., js].sum(), 1)), 5)
                          for c, js in JOINT_CLASSES.items()},
        "episodes": int(len(lengths)), "run_frames": np.bincount(lengths).tolist() if len(lengths) else [],
        "duration_ms": {k: (round(v, 2) if isinstance(v, float) else v) for k, v in
                        lognormal_fit(lengths * t.frame_ms).items()},
        "size_rel": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in lognormal_fit(peaks).items()},
        "size_rel_frames_quantiles": _q(sizes),
    }
    miss = ~det & plain[..., None]
    sections["misses"] = {}
    for name, sel in (("visible", vis), ("hidden", hid)):
        m = miss[..., J] & sel[..., J]
        runs = run_lengths(np.where(sel[..., J], m, False))
        sections["misses"][name] = {
            "joints": int(sel[..., J].sum()), "rate": round(float(m.sum() / max(sel[..., J].sum(), 1)), 5),
            "rate_by_class": {c: round(float((miss[..., js] & sel[..., js]).sum() / max(sel[..., js].sum(), 1)), 5)
                              for c, js in JOINT_CLASSES.items()},
            "run_frames": np.bincount(runs).tolist() if len(runs) else [],
            "duration_ms": {k: (round(v, 2) if isinstance(v, float) else v) for k, v in
                            lognormal_fit(runs * t.frame_ms).items()}}
    sections["hidden"] = {"share": round(float(hid[..., J].mean()), 4),
                          "detected_while_hidden_run_frames_mean": round(float(np.mean(run_lengths(
                              det[..., J] & hid[..., J]))), 2) if (det[..., J] & hid[..., J]).any() else None}
    sections["swaps"] = _swaps(t, swapped, (t.kp[..., 2] > 0) & ~((t.kp[..., 0] == 0) | (t.kp[..., 1] == 0)))
    c = t.kp[..., 2]
    ci = np.where(inlier & vis, c, np.nan)[..., J]
    ci_raw = ci - np.nanmean(ci)
    acf_c_raw = _acf(ci_raw, lags_frames)
    acf_c = _acf(_centred(ci), lags_frames)
    sections["confidence"] = {
        "above_1": int((c > 1).sum()), "max": round(float(c.max()), 4), "percentiles": list(CONF_PERCENTILES),
        **{name: [round(float(x), 4) for x in np.percentile(c[sel], CONF_PERCENTILES)] if sel.sum() > 20 else None
           for name, sel in (("visible_inliers", inlier & vis), ("hidden_inliers", inlier & hid),
                             ("outliers", outlier))},
        "lags_ms": [round(float(x), 1) for x in lags_ms], "acf": [round(a, 3) for a in acf_c_raw],
        "acf_track_mean_removed": [round(a, 3) for a in acf_c],
        **_fit_time(acf_c_raw, acf_c, lags_frames, F, t.frame_ms)}
    qruns = run_lengths(quirk[..., J])
    sections["quirks"] = {"zero_coordinate_with_confidence": int(quirk[..., J].sum()),
                          "of_detected_joints": int(det[..., J].sum()),
                          "run_frames": np.bincount(qruns).tolist() if len(qruns) else [],
                          "duration_ms": {k: (round(v, 2) if isinstance(v, float) else v) for k, v in
                                          lognormal_fit(qruns * t.frame_ms).items()}}
    return sections


def _swapped_pairs(t: Track, use: np.ndarray) -> np.ndarray:
    """(F, V, pairs) left/right pairs (:data:`LR_PAIRS`) whose detections fit the mirrored reference at half the
    error or less, among pairs whose joints are more than 5 % of the height apart."""
    sw = np.zeros(t.kp.shape[:2] + (len(LR_PAIRS),), dtype=bool)
    for k, (a, b) in enumerate(LR_PAIRS):
        d = lambda i, j: np.linalg.norm(t.kp[..., i, :2] - t.uv_ref_px[..., j, :], axis=-1)  # noqa: E731
        sep = np.linalg.norm(t.uv_ref_px[..., a, :] - t.uv_ref_px[..., b, :], axis=-1) / t.h_px
        sw[..., k] = use[..., a] & use[..., b] & (sep > 0.05) & (d(a, b) + d(b, a) < 0.5 * (d(a, a) + d(b, b)))
    return sw


def _swaps(t: Track, sw: np.ndarray, use: np.ndarray) -> dict:
    """Counts and runs of swapped pairs, limb pairs (both arm or both leg joints) and whole bodies."""
    eligible = np.stack([use[..., a] & use[..., b] & (np.linalg.norm(t.uv_ref_px[..., a, :] - t.uv_ref_px[..., b, :],
                                                                       axis=-1) / t.h_px > 0.05)
                         for a, b in LR_PAIRS], -1)
    images = eligible.any(-1)
    arms, legs = sw[..., [1, 2]].all(-1), sw[..., [4, 5]].all(-1)
    whole = sw.sum(-1) >= np.maximum(3, 0.75 * eligible.sum(-1))
    runs = run_lengths(sw.any(-1))
    return {"pair_images": int(eligible.sum()), "pairs_swapped": int(sw.sum()), "images": int(images.sum()),
            "images_swapped": int(sw.any(-1).sum()), "limb_swaps": int(((arms | legs) & ~whole).sum()),
            "whole_swaps": int(whole.sum()),
            "rate_per_image_upper_95": round(3.0 / max(int(images.sum()), 1), 5) if not sw.any() else None,
            "run_frames": np.bincount(runs).tolist() if len(runs) else []}


def fitted_model(sections: dict[str, dict], *, image_height_px: float, false_people_bound: float) -> dict:
    """The :class:`~dome_calib.synth.detector_model.DetectorModel` options these statistics give (the measured
    ones; the chosen ones stay out): per-joint noise with left and right averaged (the neck and body centre take
    the shoulders' and hips' values), the swap rates within the 95 % bound of a capture without swaps (a third
    whole-body, two thirds one limb pair), false people at ``false_people_bound`` (per image)."""
    n, nt, o, m, c = (sections[k] for k in ("noise", "noise_time", "outliers", "misses", "confidence"))
    per = n["sigma_rel_per_joint"]
    pair = {k: round(0.5 * (per[f"l_{k}"] + per[f"r_{k}"]), 4) for k in ("shoulder", "elbow", "wrist", "hip", "knee",
                                                                          "ankle", "eye", "ear")}
    side = [pair[k] for k in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")]
    lognormal = lambda d, digits=1: Lognormal(round(d["median"], digits), round(d["log_sd"], 2))  # noqa: E731
    bound = sections["swaps"]["rate_per_image_upper_95"] or 0.0
    q = sections["quirks"]
    return {
        "noise_rel19": (pair["shoulder"], round(per["nose"], 4), pair["hip"], *side, *side, pair["eye"], pair["ear"],
                        pair["eye"], pair["ear"]),
        "noise_ref_net_px": round(n["h_px_median"] * 368.0 / image_height_px, 0),
        "hidden_noise": round(n["sigma_rel_hidden_over_visible"], 2),
        "noise_bias_share": round(nt["bias_share"], 2), "noise_white_share": round(nt["white_share"], 2),
        "noise_tau_ms": round(nt["tau_ms"], 0),
        "outlier_wrists": round(o["rate_by_class"]["wrists"], 3),
        "outlier_limbs": round(o["rate_by_class"]["limbs"], 3),
        "outlier_face": round(o["rate_by_class"]["face"], 3), "outlier_ms": lognormal(o["duration_ms"]),
        "outlier_size_rel": lognormal(o["size_rel"], 4), "k_outlier": o["k_outlier"],
        "miss_base": round(m["visible"]["rate"], 4), "miss_ms": lognormal(m["visible"]["duration_ms"]),
        "miss_self_face": round(m["hidden"]["rate_by_class"]["face"], 2),
        "miss_self_body": round(m["hidden"]["rate_by_class"]["limbs"], 3),
        "miss_self_ms": lognormal(m["hidden"]["duration_ms"]),
        "swap_lr": round(bound / 3.0, 4), "swap_limb": round(2.0 * bound / 3.0, 4),
        "false_people_per_view": round(false_people_bound, 4),
        "zero_coordinate": round(q["zero_coordinate_with_confidence"] / q["of_detected_joints"], 5),
        "zero_ms": lognormal(q["duration_ms"]),
        "conf_visible": tuple(round(x, 3) for x in c["visible_inliers"]),
        "conf_hidden": tuple(round(x, 3) for x in c["hidden_inliers"]),
        "conf_outlier": tuple(round(x, 3) for x in c["outliers"]),
        "conf_bias_share": round(c["bias_share"], 2), "conf_white_share": round(c["white_share"], 2),
        "conf_tau_ms": round(c["tau_ms"], 0)}


__all__ = ["ACF_LAGS_MS", "JOINT_CLASSES", "LR_PAIRS", "Track", "fitted_model", "hysteresis_runs",
           "lognormal_fit", "measure", "run_lengths"]
