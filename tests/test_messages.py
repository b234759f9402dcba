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
        assert lines[0].startswith(f"irdetect {command[0]}: error: bad.h5: frames "), lines
        expected = "float32's range" if kind == "huge" else "hold NaN or inf values"
        assert expected in lines[0]
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
