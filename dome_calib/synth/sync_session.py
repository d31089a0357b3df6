"""Synthetic sync sessions with known truth, made with the LTC encoder (:mod:`timecode.encoder`).

True time is the sample clock of ``ltc.wav`` before any restart cut: ``T = original sample / sample_rate``.
Every clock is a line against it (offset, drift in ppm); universal time is the HD LTC timeline, so the truth of
an event at true time ``T`` is ``(count0 + (T - hd_offset_s) * hd_fps * (1 + hd_drift)) * 1000 / hd_fps``.
``truth.json`` (beside ``session.json``, ignored by the loader) holds the true universal time of every frame.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated

import numpy as np
import soundfile as sf

from dome_calib.io_utils import atomic_path, atomic_write_text
from timecode.encoder import EncoderOptions, encode_ltc_labels
from timecode.labels import format_labels, frames_to_labels, label_to_frames
from timecode.rates import FrameRate, parse_rate
from timecode.sync.session import FORMAT, VERSION, write_session_json
from dome_calib.options import AtLeast, Field, options
from dome_calib.schema import Finite, NonNegFinite, PosFinite

#: The recordings are written as 24-bit PCM, as the dome's audio interfaces and Kinect microphones record (the
#: quantisation, 2^-23 of full scale, is ~120 dB under the LTC's own noise): a float WAV carries libsndfile's PEAK
#: chunk, which stamps the time of writing, so the same capture would not be the same bytes twice.
WAV_SUBTYPE = "PCM_24"
BLOCK_SAMPLES = 256  # Kinect v2 audio sub-frame: 256 samples = 16 ms at 16 kHz


@options
class SynthSessionOptions:
    """What to simulate. Drifts are ppm against the true clock (+ = the clock runs fast)."""

    seed: AtLeast(0) = 0
    seq: str = "synth_sync"
    duration_s: PosFinite = 6.0
    sample_rate: AtLeast(1) = 48000
    vga_rate: str = "25"
    hd_rate: str = "29.97df"
    vga_start: str = "10:00:00:00"  # label of the first VGA LTC frame in ltc.wav
    hd_start: str = "10:00:00;00"  # label of the first HD LTC frame in ltc.wav
    vga_drift_ppm: Finite = 23.0
    hd_drift_ppm: Finite = -17.0
    vga_offset_s: Finite = 0.01237  # true time of the first VGA LTC frame start
    hd_offset_s: Finite = 0.00711
    snr_db: Finite = 30.0  # LTC to noise, per channel of ltc.wav
    level_dbfs: Annotated[float, Field(le=0)] = -12.0
    vga_jump_at_s: NonNegFinite | None = None  # the VGA generator is re-jammed here ...
    vga_jump_frames: int = 1000  # ... and its labels leap by this many frames
    hd_jump_at_s: NonNegFinite | None = None
    hd_jump_frames: int = -40000
    restart_at_s: NonNegFinite | None = None  # ltc.wav loses restart_gap_s of audio here (recorder restarted)
    restart_gap_s: NonNegFinite = 0.4137
    dropped_frames: AtLeast(0) = 2  # frames missing from each camera stream (VGA, HD, Kinect colour and depth)
    hd_timecode_every: AtLeast(0) = 1  # HD frames carry an embedded timecode every this many frames (0: none)
    n_kinects: AtLeast(0) = 2
    kinect_nodes: tuple[str, ...] | None = None  # node names (default KINECTNODE1..n_kinects), e.g. the dome's
    kinect_missing_audio: tuple[str, ...] = ()  # nodes whose microphone recorded nothing
    kinect_sample_rate: AtLeast(1) = 16000
    kinect_max_drift_ppm: NonNegFinite = 50.0  # device and audio clocks drift uniformly within +-this
    kinect_snr_db: Finite = 25.0
    kinect_level_dbfs: Annotated[float, Field(le=0)] = -20.0
    kinect_frame_jitter_us: NonNegFinite = 200.0  # std of colour/depth frame timestamps
    kinect_block_jitter_us: NonNegFinite = 500.0  # std of audio block timestamps
    kinect_depth_phase_ms: Finite = 6.25  # depth exposure after colour exposure
    kinect_audio_gap_at_s: NonNegFinite | None = None  # every Kinect loses audio blocks here (USB hiccup) ...
    kinect_audio_gap_blocks: AtLeast(0) = 23  # ... this many blocks: the file just lacks them


@dataclass(kw_only=True)
class SynthTruth:
    """True universal time (ms) of every frame, keyed like the sync tables: "vga", "hd", "KINECTNODE1/color"."""

    index: dict[str, np.ndarray] = field(default_factory=dict)
    univ_ms: dict[str, np.ndarray] = field(default_factory=dict)
    jitter_us: dict[str, np.ndarray] = field(default_factory=dict)  # simulated timestamp error of each frame, us
    params: dict = field(default_factory=dict)
    ltc_frames: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # channel -> (count,
    # start sample in its file) of every encoded LTC frame: "vga", "hd", "KINECTNODE1"; for decoder-free tests


def _encode(labels: np.ndarray, rate: FrameRate, sample_rate: int, offset_samples: float, drift_ppm: float,
            level_dbfs: float, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    enc = encode_ltc_labels(labels, fps=rate, sample_rate=sample_rate, options=EncoderOptions(
        start_offset_samples=offset_samples, drift_ppm=drift_ppm, level_dbfs=level_dbfs, tail_samples=0))
    out = np.zeros(n_samples)
    m = min(n_samples, enc.samples.size)
    out[:m] = enc.samples[:m]
    return out, enc.frame_start_samples


def _labels(start: str, n: int, rate: FrameRate, jump_at: int | None, jump: int) -> np.ndarray:
    """Label counts of ``n`` consecutive frames from ``start``, leaping by ``jump`` frames at frame ``jump_at``."""
    c = label_to_frames(start, rate) + np.arange(n)
    if jump_at is not None:
        c[jump_at:] += jump
    return np.mod(c, rate.frames_per_day)


def _drop(rng: np.random.Generator, index: np.ndarray, n: int) -> np.ndarray:
    if n <= 0 or index.size < 10:
        return index
    gone = rng.choice(np.arange(2, index.size - 2), size=n, replace=False)
    return np.delete(index, gone)


def make_session(folder: str | Path, options: SynthSessionOptions | None = None) -> SynthTruth:
    """Write a synthetic session into ``folder`` (see :mod:`timecode.sync.session`) and return its truth."""
    o = options or SynthSessionOptions()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(o.seed)
    fs = o.sample_rate
    vr, hr = parse_rate(o.vga_rate), parse_rate(o.hd_rate)
    n_total = int(o.duration_s * fs)
    truth = SynthTruth(params=asdict(o))
    hd_fps = float(hr.fps)
    count0 = label_to_frames(o.hd_start, hr)

    def univ_ms(t_s: np.ndarray) -> np.ndarray:
        return (count0 + (t_s - o.hd_offset_s) * hd_fps * (1 + o.hd_drift_ppm * 1e-6)) * (1000.0 / hd_fps)

    chans, ticks_s, counts = [], {}, {}
    for key, rate, start, drift, off, jump_at, jump in (
            ("vga", vr, o.vga_start, o.vga_drift_ppm, o.vga_offset_s, o.vga_jump_at_s, o.vga_jump_frames),
            ("hd", hr, o.hd_start, o.hd_drift_ppm, o.hd_offset_s, o.hd_jump_at_s, o.hd_jump_frames)):
        period_s = 1.0 / float(rate.fps) / (1 + drift * 1e-6)
        n = int((o.duration_s - off) / period_s) - 1
        j_at = None if jump_at is None else int(round((jump_at - off) / period_s))
        counts[key] = _labels(start, n, rate, j_at, jump)
        audio, starts = _encode(frames_to_labels(counts[key], rate), rate, fs, off * fs, drift, o.level_dbfs, n_total)
        chans.append(audio + rng.normal(0, 10 ** (o.level_dbfs / 20) / 10 ** (o.snr_db / 20), n_total))
        ticks_s[key] = starts / fs
        file_starts = starts.copy()
        if o.restart_at_s is not None:
            c0, gap = int(o.restart_at_s * fs), int(o.restart_gap_s * fs)
            lost = (starts >= c0 - fs / float(rate.fps)) & (starts < c0 + gap)  # frames the cut spoils
            file_starts = np.where(starts >= c0 + gap, starts - gap, starts)
            file_starts[lost] = np.nan
        ok = np.isfinite(file_starts)
        truth.ltc_frames[key] = (counts[key][ok], file_starts[ok])
    stereo = np.stack(chans, axis=1)
    if o.restart_at_s is not None:
        c0 = int(o.restart_at_s * fs)
        stereo = np.delete(stereo, np.s_[c0:c0 + int(o.restart_gap_s * fs)], axis=0)
    with atomic_path(folder / "ltc.wav") as tmp:
        sf.write(tmp, stereo, fs, subtype=WAV_SUBTYPE, format="WAV")

    streams = {}
    for key, rate, base in (("vga", vr, 100), ("hd", hr, 5000)):
        n = ticks_s[key].size
        index = _drop(rng, np.arange(3, n - 3) + base, o.dropped_frames)
        tick = index - base
        truth.index[key], truth.univ_ms[key] = index, univ_ms(ticks_s[key][tick])
        truth.jitter_us[key] = np.zeros(index.size)
        labels = format_labels(frames_to_labels(counts[key][tick], rate), rate.drop_frame)
        st: dict = {"clock": key, "index": index.tolist()}
        if key == "hd" and o.hd_timecode_every > 0:
            st["timecode"] = [lb if k % o.hd_timecode_every == 0 else None for k, lb in enumerate(labels)]
        else:
            st["ref_index"], st["ref_timecode"] = int(index[0]), labels[0]
        streams[key] = st

    kinect_doc, kinect_ts = {}, {}
    hd_ticks_s = ticks_s["hd"]
    nodes = o.kinect_nodes if o.kinect_nodes is not None else [f"KINECTNODE{i}" for i in range(1, o.n_kinects + 1)]
    for name in nodes:
        d_audio, d_dev = rng.uniform(-o.kinect_max_drift_ppm, o.kinect_max_drift_ppm, 2)
        t0 = 0.2 + rng.uniform(0, 0.2)  # true time of the first Kinect audio sample
        dur = o.duration_s - t0 - 0.2 - rng.uniform(0, 0.2)
        kfs = o.kinect_sample_rate * (1 + d_audio * 1e-6)  # Kinect audio samples per true second
        tau0 = int(rng.integers(10**10, 10**11))
        dev = lambda t_s: tau0 + t_s * 1e7 * (1 + d_dev * 1e-6)  # noqa: E731  true s -> device 100 ns
        n_k = int(dur * kfs)
        j0 = int(np.searchsorted(hd_ticks_s, t0 + 0.002))
        j1 = int(np.searchsorted(hd_ticks_s, t0 + dur - 0.05))
        p = ((1 + o.hd_drift_ppm * 1e-6) / (1 + d_audio * 1e-6) - 1) * 1e6
        audio, kstarts = _encode(frames_to_labels(counts["hd"][j0:j1], hr), hr, o.kinect_sample_rate,
                           (hd_ticks_s[j0] - t0) * kfs, p, o.kinect_level_dbfs, n_k)
        truth.ltc_frames[name] = (counts["hd"][j0:j1], kstarts)
        audio += rng.normal(0, 10 ** (o.kinect_level_dbfs / 20) / 10 ** (o.kinect_snr_db / 20), n_k)
        first = np.arange(0, n_k - BLOCK_SAMPLES, BLOCK_SAMPLES)
        block_dev = np.round(dev(t0 + first / kfs) + rng.normal(0, o.kinect_block_jitter_us * 10, first.size))
        if o.kinect_audio_gap_at_s is not None:  # lost blocks: removed from the file, later ones move up
            b0 = int((o.kinect_audio_gap_at_s - t0) * kfs) // BLOCK_SAMPLES
            gap = o.kinect_audio_gap_blocks * BLOCK_SAMPLES
            c0 = b0 * BLOCK_SAMPLES
            audio = np.delete(audio, np.s_[c0:c0 + gap])
            keep = (first < c0) | (first >= c0 + gap)
            first, block_dev = np.where(first >= c0 + gap, first - gap, first)[keep], block_dev[keep]
            kc, ks = truth.ltc_frames[name]
            ok = (ks < c0 - o.kinect_sample_rate / hd_fps) | (ks >= c0 + gap)
            truth.ltc_frames[name] = (kc[ok], np.where(ks >= c0 + gap, ks - gap, ks)[ok])
        node_dir = folder / "kinect" / name
        node_dir.mkdir(parents=True, exist_ok=True)
        has_audio = name not in o.kinect_missing_audio
        if has_audio:
            with atomic_path(node_dir / "audio.wav") as tmp:
                sf.write(tmp, audio, o.kinect_sample_rate, subtype=WAV_SUBTYPE, format="WAV")
        ts: dict = {"audio_blocks": {"first_sample": first.tolist(),
                                     "device_time_100ns": block_dev.astype(np.int64).tolist()}}
        period = 1 / 30 / (1 + d_dev * 1e-6)
        tc0 = t0 + 0.05 + rng.uniform(0, 0.03)
        n_frames = int((t0 + dur - 0.05 - tc0 - o.kinect_depth_phase_ms * 1e-3) / period)
        for kind, phase in (("color", 0.0), ("depth", o.kinect_depth_phase_ms * 1e-3)):
            index = _drop(rng, np.arange(n_frames), o.dropped_frames)
            t = tc0 + phase + index * period
            jit_100ns = rng.normal(0, o.kinect_frame_jitter_us * 10, index.size)
            stamp = np.round(dev(t) + jit_100ns).astype(np.int64)
            ts[kind] = {"index": index.tolist(), "device_time_100ns": stamp.tolist()}
            key = f"{name}/{kind}"
            truth.index[key], truth.univ_ms[key] = index, univ_ms(t)
            truth.jitter_us[key] = (stamp - dev(t)) / 10 / (1 + d_dev * 1e-6)
        kinect_doc[name] = {"audio": f"kinect/{name}/audio.wav" if has_audio else None, "audio_channel": 0,
                            "timestamps": f"kinect/{name}/timestamps.json"}
        kinect_ts[name] = ts
        truth.params[f"{name}_drift_ppm"] = {"audio": float(d_audio), "device": float(d_dev)}

    doc = {"format": FORMAT, "version": VERSION, "seq": o.seq,
           "ltc": {"file": "ltc.wav", "vga_channel": 0, "hd_channel": 1, "vga_rate": vr.name, "hd_rate": hr.name},
           "streams": streams, "kinect": kinect_doc}
    write_session_json(folder, doc, kinect_ts)
    atomic_write_text(folder / "truth.json", json.dumps({
        "params": truth.params,
        "streams": {k: {"index": truth.index[k].tolist(), "univ_ms": truth.univ_ms[k].tolist(),
                        "jitter_us": truth.jitter_us[k].tolist()} for k in truth.index}}))
    return truth


def load_truth(folder: str | Path) -> SynthTruth:
    """Read ``truth.json`` written by :func:`make_session`."""
    data = json.loads((Path(folder) / "truth.json").read_text())
    t = SynthTruth(params=data["params"])
    for k, v in data["streams"].items():
        t.index[k] = np.asarray(v["index"], np.int64)
        t.univ_ms[k] = np.asarray(v["univ_ms"], float)
        t.jitter_us[k] = np.asarray(v["jitter_us"], float)
    return t
