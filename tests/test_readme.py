"""The README's quick tour runs as written, top to bottom, in an empty folder."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from tests.conftest import ROOT, real_sequence

MARKER = "<!-- quick-tour:"


def quick_tour() -> str:
    """The sh block that follows the quick-tour marker in README.md."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert MARKER in text, "README.md lost its quick-tour marker"
    found = re.search(r"```sh\n(.*?)```", text[text.index(MARKER):], re.S)
    assert found, "no sh block after the quick-tour marker"
    return found.group(1)


def test_quick_tour_covers_every_command():
    commands = {line.split()[1] for line in quick_tour().splitlines()
                if line.startswith("irdetect ")}
    assert commands >= {"simulate", "process", "evaluate", "video", "plot", "track",
                        "simulate-scans", "initiate", "convert", "info", "export"}
    assert "--profile fast" in quick_tour() and "$REAL/" in quick_tour()


@pytest.mark.slow
def test_quick_tour_runs_in_an_empty_folder(tmp_path):
    real_sequence("easy1")                       # skipped without ../shared/data/real
    env = dict(os.environ, REPO=str(ROOT),
               PATH=os.pathsep.join([os.path.dirname(sys.executable), os.environ["PATH"]]))
    run = subprocess.run(["bash", "-euo", "pipefail", "-c", quick_tour()], cwd=tmp_path,
                         env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    for name in ("seq.irdetect.h5", "seq.fast.h5", "seq.mp4", "seq.png",
                 "export/tracks_mot.txt", "harbour.track.h5", "init.h5", "easy1.irdetect.h5",
                 "easy1.h5"):
        assert (tmp_path / name).is_file(), name
    assert "legend: " in run.stdout and "error" not in run.stderr.lower()
