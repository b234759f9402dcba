"""One truth-discovery rule for evaluate, video and plot: a recording folder's truth.txt,
the sequence's /truth, or a given file; the same message when none is found."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from irdetect.io import NO_TRUTH, find_truth, open_sequence, write_sequence
from irdetect.simulate import simulate


@pytest.fixture
def recording(tmp_path):
    """A recording folder rec/{frames/*.png, truth.txt} (8-bit, one target) and the same
    frames as an HDF5 file without /truth; returns (folder, truth)."""
    frames, truth = simulate("wan2008", rng=6, n_frames=36, height=40, width=48,
                             n_targets=1, snr=8.0, directions=[20.0], dtype="uint8")
    (tmp_path / "rec" / "frames").mkdir(parents=True)
    for i, frame in enumerate(frames):
        assert cv2.imwrite(str(tmp_path / "rec" / "frames" / f"{i:04d}.png"), frame)
    np.savetxt(tmp_path / "rec" / "truth.txt", np.column_stack([truth["x"], truth["y"]]),
               fmt="%.3f")
    write_sequence(tmp_path / "bare.h5", frames)
    return tmp_path / "rec", truth


def test_find_truth_follows_one_rule(recording, tmp_path):
    folder, truth = recording
    for sequence in (folder, folder / "frames"):
        found = find_truth(sequence=sequence)
        np.testing.assert_allclose(found.table["x"], truth["x"], atol=1e-3)
        assert found.path.endswith("truth.txt") and found.shape == (36, 40, 48)
    with open_sequence(folder) as src:
        assert len(find_truth(sequence=src).table) == 36
    # a given file wins over the sequence's; a folder given is read as a recording
    assert find_truth(folder / "truth.txt", sequence=tmp_path / "bare.h5").shape is None
    assert len(find_truth(folder).table) == 36
    for kwargs in ({"sequence": tmp_path / "bare.h5"}, {"given": tmp_path / "bare.h5"}, {}):
        with pytest.raises(ValueError, match="no ground truth"):
            find_truth(**kwargs)


def test_every_command_finds_a_recording_folders_truth(recording, cli, tmp_path):
    folder, _ = recording
    code, _, err = cli("process", folder, "-o", "rec.h5", "-q")
    assert code == 0, err
    code, out, err = cli("evaluate", "rec.h5")
    assert code == 0 and "pd" in out, err
    code, _, err = cli("video", folder, "rec.h5", "-o", "frames_out", "--truth", "-q")
    assert code == 0, err
    code, _, err = cli("plot", "rec.h5", "--sequence", folder, "-o", "rec.png", "--truth")
    assert code == 0, err


def test_no_truth_is_the_same_line_for_every_command(recording, cli, tmp_path):
    code, _, err = cli("process", tmp_path / "bare.h5", "-o", "bare.irdetect.h5", "-q")
    assert code == 0, err
    runs = [("evaluate", "bare.irdetect.h5"),
            ("video", "bare.h5", "bare.irdetect.h5", "-o", "v_out", "--truth"),
            ("plot", "bare.irdetect.h5", "-o", "b.png", "--truth")]
    for argv in runs:
        code, _, err = cli(*argv)
        assert code == 2, (argv, err)
        assert err.strip().endswith(NO_TRUTH) and len(err.strip().splitlines()) == 1, err
