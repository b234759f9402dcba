"""Profiles (``--profile fast`` / ``paper``), ``--threads`` and the detector's sampled
statistics. Not timed: the speed is measured by scripts/bench_throughput.py. Each test
draws the scene it then processes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from irdetect.cli import main
from irdetect.config import ProcessConfig
from irdetect.detect import detect
from irdetect.errors import InputError
from irdetect.io import read_results, write_sequence
from irdetect.metrics.detection import score_detections
from irdetect.pipeline import detect_sequence
from irdetect.profiles import load_profile, profile_names
from irdetect.simulate import simulate


def _score(out, truth, n_frames, shape):
    return score_detections(out["detections"], truth, n_frames=n_frames, length=12, step=12,
                            shape=shape)


def test_every_profile_loads_and_a_config_file_goes_on_top(tmp_path):
    assert {"default", "fast", "paper"} <= set(profile_names())
    for name in profile_names():
        assert isinstance(load_profile(name), ProcessConfig)
    assert load_profile("default") == ProcessConfig()
    fast = load_profile("fast")
    assert fast.correlate.verify == 0 and fast.detect.sample == 4
    assert load_profile("paper").combine.projection == "max"
    extra = tmp_path / "extra.toml"
    extra.write_text("[detect]\nk = 4.5\n[combine]\nlength = 6\nstep = 6\n")
    mixed = load_profile("fast", extra)
    assert mixed.detect.k == 4.5 and mixed.detect.sample == 4       # file over profile
    assert mixed.combine.length == 6 and mixed.correlate.verify == 0
    with pytest.raises(InputError, match="--profile quick: unknown profile.*fast"):
        load_profile("quick")
    extra.write_text("[detect]\nkk = 1\n")
    with pytest.raises(InputError, match="detect.kk"):
        load_profile("fast", extra)


def test_fast_profile_finds_snr4_targets_and_ignores_noise():
    frames, truth = simulate("wan2008", snr=4.0, rng=11, n_frames=72)
    s = _score(detect_sequence(frames, load_profile("fast")), truth, len(frames),
               frames.shape[1:])
    assert s["pd"] >= 0.9, s
    assert s["false"] <= 2, s
    # pure noise (no targets): under one confirmed noise chain per window (measured about
    # 2 per Mpx-window, docs/results/profiles.md), far fewer than the paper's variant
    noise, none = simulate("wan2008", snr=4.0, rng=12, n_frames=72, n_targets=0,
                           directions=[])
    fast = detect_sequence(noise, load_profile("fast"))["detections"]
    paper = detect_sequence(noise, load_profile("paper"))["detections"]
    assert len(none) == 0 and len(fast) <= 72 // 12 and len(paper) >= 3 * len(fast)


def test_fast_profile_keeps_clutter_out():
    frames, truth = simulate("clutter", rng=5, n_frames=72)
    s = _score(detect_sequence(frames, load_profile("fast")), truth, len(frames),
               frames.shape[1:])
    assert s["pd"] >= 0.6, s
    assert s["false"] <= 2, s


def test_cli_profile_and_threads_give_the_same_tables(tmp_path):
    frames, _ = simulate("wan2008", snr=4.0, rng=13, n_frames=72)
    seq = tmp_path / "seq.h5"
    write_sequence(seq, frames)
    runs = {}
    for name, extra in (("t1", ["--threads", "1"]), ("t3", ["--threads", "3"]),
                        ("default", [])):
        out = tmp_path / f"{name}.h5"
        assert main(["process", str(seq), "-o", str(out), "--profile", "fast", *extra]) == 0
        runs[name] = read_results(out)
    for name in ("candidates", "detections", "segments", "tracks"):
        assert runs["t1"][name].tobytes() == runs["t3"][name].tobytes()
        assert runs["t1"][name].tobytes() == runs["default"][name].tobytes()
    assert len(runs["t1"]["detections"]) > 0
    # the results file records the profile's resolved configuration
    import h5py
    with h5py.File(tmp_path / "t1.h5") as f:
        cfg = json.loads(f.attrs["config"])
    assert cfg["correlate"]["verify"] == 0 and cfg["detect"]["sigma"] == "global"
    assert main(["process", str(seq), "-o", str(tmp_path / "x.h5"), "--threads", "0"]) == 2
    assert main(["process", str(seq), "-o", str(tmp_path / "x.h5"), "--profile", "no"]) == 2
    assert not (tmp_path / "x.h5").exists()


def test_detect_statistics_on_a_coarser_grid_find_the_same_streak():
    rng = np.random.default_rng(6)
    img = rng.normal(size=(128, 128)).astype(np.float32)
    img[60, 40:52] += 4.0                     # a horizontal streak
    fine = detect(img, k=4.0)
    coarse = detect(img, k=4.0, sample=4, sigma="global")
    for det in (fine, coarse):
        assert det.mask[60, 42:50].all(), np.flatnonzero(det.mask[60])
        assert det.direction[60, 46] == 0
        assert det.count < 60                 # a few noise pixels at most besides it
    with pytest.raises(ValueError, match="sample"):
        detect(img, sample=0)
