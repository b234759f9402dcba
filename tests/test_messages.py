"""Bad input ends in exactly one line that names what to change (issue 29): the option
whose value is bad, the file whose content is; Python warnings shown
(``PYTHONWARNINGS=default``) do not come before it."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import h5py
import numpy as np
import pytest


def _frames(kind: str) -> np.ndarray:
    rng = np.random.default_rng(3)
    frames = rng.normal(100, 5, (40, 32, 32))
    if kind == "nan":
        frames[20, 4, 5] = np.nan
    elif kind == "nan-frame":
        frames[0] = np.nan
    elif kind == "inf":                  # +inf and -inf: their sum is NaN ("invalid value")
        frames[3, 4, 5], frames[3, 4, 6] = np.inf, -np.inf
    elif kind == "huge":                 # finite float64 beyond float32's range
        frames[3, 4, 5] = frames[3, 4, 6] = 1e308
    return frames.astype(np.float64 if kind == "huge" else np.float32)


#: what the one line says of each (which frames, how many pixels, the first one)
EXPECTED = {
    "nan": "frame 20 holds NaN or inf values (1 px in frames 0..",
    "nan-frame": "frame 0 holds NaN or inf values (the whole frame;",
    "inf": "frame 3 holds NaN or inf values (2 px in frames 0..",
    "huge": "float32's range",
}


@pytest.mark.parametrize("kind", ["nan", "nan-frame", "inf", "huge"])
def test_bad_values_give_one_line_with_warnings_shown(tmp_path, kind):
    with h5py.File(tmp_path / "bad.h5", "w") as f:
        f["frames"] = _frames(kind)
    env = dict(os.environ, PYTHONWARNINGS="default")
    commands = [["process", "bad.h5", "-o", "r.h5"], ["track", "bad.h5", "-o", "t.h5"]]
    if kind != "huge":                   # convert keeps finite float64 values as stored
        commands.append(["convert", "bad.h5", "-o", "c.h5"])
    for command in commands:
        run = subprocess.run([sys.executable, "-m", "irdetect", *command], cwd=tmp_path,
                             env=env, capture_output=True, text=True, timeout=120)
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 2 and len(lines) == 1, (command, run.stderr)
        assert lines[0].startswith(f"irdetect {command[0]}: error: bad.h5: frame"), lines
        assert EXPECTED[kind] in lines[0], lines[0]
        assert not any(p.name not in ("bad.h5",) for p in tmp_path.iterdir()), command


@pytest.mark.filterwarnings("always")
def test_held_warnings_are_dropped_on_a_one_line_error_and_shown_otherwise(monkeypatch,
                                                                          capsys):
    from irdetect import cli
    from irdetect.commands import info
    from irdetect.errors import InputError

    def warn_then(outcome):
        def run(args):
            warnings.warn("a library's warning", RuntimeWarning)
            if outcome == "error":
                raise InputError("bad input", "x.h5")
            return 0
        return run

    shown = []
    monkeypatch.setattr(warnings, "showwarning", lambda *a, **k: shown.append(a[0]))
    monkeypatch.setattr(info, "run", warn_then("error"))
    assert cli.main(["info", "x.h5"]) == 2
    assert capsys.readouterr().err == "irdetect info: error: x.h5: bad input\n"
    assert shown == []
    monkeypatch.setattr(info, "run", warn_then("ok"))
    assert cli.main(["info", "x.h5"]) == 0
    assert [str(w) for w in shown] == ["a library's warning"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A small sequence with its results, and a scans file, made once."""
    from irdetect.cli import main

    folder = tmp_path_factory.mktemp("files")
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        for argv in (["simulate", "seq.h5", "--frames", "36", "--size", "48x40", "--seed", "1"],
                     ["process", "seq.h5", "-o", "res.h5"],
                     ["simulate-scans", "scans.h5", "--scans", "6", "--seed", "1"]):
            assert main(argv + ["-q"]) == 0, argv
    finally:
        os.chdir(cwd)
    return folder


#: (command line, what the one line must say): every bad value names its option
BAD_OPTIONS = [
    ("simulate s.h5 --size 0x0", "--size 0x0: height must be >= 1, got 0"),
    ("simulate s.h5 --size 10x10", "--size 10x10: frames of 10x10 leave no room"),
    ("simulate s.h5 --size 9000x9000", "--size 9000x9000: frames of 9000x9000 px: at most"),
    ("simulate s.h5 --frames 0", "--frames 0: n_frames must be >= 1, got 0"),
    ("simulate s.h5 --frames 5000", "--frames 5000: targets at"),
    ("simulate s.h5 --targets -1", "--targets -1: n_targets must be >= 0"),
    ("simulate s.h5 --snr -1", "--snr -1: snr must be >= 0"),
    ("simulate s.h5 --speed 3 1", "--speed 3 1: speed must be [min, max]"),
    ("simulate s.h5 --noise-sigma -1", "--noise-sigma -1: noise_sigma must be >= 0"),
    ("simulate s.h5 --psf-sigma 0", "--psf-sigma 0: psf_sigma must be > 0"),
    ("simulate s.h5 --camera-jitter -1", "--camera-jitter -1: camera_jitter must be"),
    ("simulate s.h5 --camera-pan 1000 0", "--camera-pan 1000 0: targets at 1 px/frame and a "
     "camera pan of 1000 px/frame leave"),
    ("simulate s.h5 --agc 0.15 0", "--agc 0.15 0: agc_period must be >= 1, got 0"),
    ("simulate s.h5 --agc 0.15 2.5", "--agc 0.15 2.5: the period must be a whole number"),
    ("simulate s.h5 --agc -2 20", "--agc -2 20: agc_step must be a number > -1"),
    ("simulate s.h5 --seed -1", "--seed must be an integer >= 0, got -1"),
    ("simulate s.h5 --scenario harbour --frames 0", "--frames 0: n_frames must be >= 1"),
    ("simulate s.h5 --scenario harbour --noise-sigma -1", "--noise-sigma -1: noise_sigma"),
    ("simulate s.h5 --scenario harbour --speed 3 4", "--speed 3 4 does not apply to the "
     "harbour scene"),
    ("simulate s.h5 --scenario harbour --agc 0.1 5", "--agc 0.1 5 does not apply to the "
     "harbour scene"),
    ("simulate-scans s.h5 --clutter-density -1", "--clutter-density -1: clutter_density "
     "must be a number >= 0"),
    ("simulate-scans s.h5 --clutter-mean -1", "--clutter-mean -1: clutter_mean must be"),
    ("simulate-scans s.h5 --scans 0", "--scans 0: n_scans must be >= 1"),
    ("simulate-scans s.h5 --clutter-density 1e9", "--clutter-density 1e+09: 1.44e+14 "
     "clutter points"),
    ("simulate-scans s.h5 --seed -1", "--seed must be an integer >= 0, got -1"),
    ("plot res.h5 -o p.png --gamma 0", "--gamma 0: gamma must be a positive number"),
    ("video seq.h5 res.h5 -o v.mp4 --gamma -1", "--gamma -1: gamma must be"),
    ("video seq.h5 res.h5 -o v.mp4 --percentiles 99 1", "--percentiles 99 1: need 0 <= low"),
    ("initiate scans.h5 -o i.h5 --sigma 0", "--sigma must be a number > 0, got 0"),
    ("initiate scans.h5 -o i.h5 --sigma -1", "--sigma must be a number > 0, got -1"),
    ("initiate scans.h5 -o i.h5 --sigma-range -1", "--sigma-range must be a number > 0"),
    ("initiate scans.h5 -o i.h5 --sigma-azimuth -1", "--sigma-azimuth must be a number > 0"),
    ("initiate scans.h5 -o i.h5 --false-tracks -1", "--false-tracks must be a number >= 0"),
    ("process seq.h5 -o r.h5 --profile nope", "--profile nope: unknown profile"),
    ("track seq.h5 -o t.h5 --profile nope", "--profile nope: unknown profile"),
]


@pytest.mark.parametrize("command, expected", BAD_OPTIONS, ids=[c for c, _ in BAD_OPTIONS])
def test_every_bad_value_names_its_option(files, monkeypatch, capsys, command, expected):
    from irdetect.cli import main

    monkeypatch.chdir(files)
    before = set(files.iterdir())
    argv = command.split()
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and err == f"irdetect {argv[0]}: error: {err.split(': error: ', 1)[1]}"
    assert len(err.splitlines()) == 1 and expected in err, err
    assert set(files.iterdir()) == before


@pytest.mark.parametrize("command", ["evaluate seq.h5", "plot seq.h5 -o p.png",
                                     "export seq.h5 --format csv -o out",
                                     "video seq.h5 seq.h5 -o v.mp4", "evaluate seq.npy"])
def test_a_sequence_given_for_results_says_to_process_it_first(files, tmp_path, monkeypatch,
                                                               capsys, command):
    from irdetect.cli import main

    (tmp_path / "seq.h5").symlink_to(files / "seq.h5")
    np.save(tmp_path / "seq.npy", np.zeros((12, 8, 8), np.float32))
    monkeypatch.chdir(tmp_path)
    before = set(tmp_path.iterdir())
    assert main(command.split()) == 2
    err = capsys.readouterr().err
    what = "a sequence (it holds /frames)" if ".h5" in command else "a sequence"
    assert err == (f"irdetect {command.split()[0]}: error: {command.split()[1]}: {what}, not "
                   "a results file: run `irdetect process` (or `track`) on it and give the "
                   "results file it writes\n")
    assert set(tmp_path.iterdir()) == before


def test_nonfinite_message_names_the_frames_and_the_first_pixel():
    from irdetect.errors import InputError
    from irdetect.io.sources import check_values

    frames = np.ones((12, 16, 20), np.float32)
    frames[2:9, 10, 11] = np.inf         # x 11, y 10 in frames 2..8
    frames[5, 0, 0] = np.nan
    with pytest.raises(InputError) as err:
        check_values(frames, 30, "seq.h5")
    assert str(err.value).endswith(
        "frames 32, 33, 34 and 4 more hold NaN or inf values (8 px in frames 30..41, the "
        "first at x 11, y 10 of frame 32; irdetect needs finite pixel values)")
    check_values(np.ones((3, 4, 4), np.float32), 0, "seq.h5")      # finite: no error
