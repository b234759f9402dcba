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


def _write_masks(folder, truth, shape, radius=1):
    """One 8-bit mask per frame: a filled disc of ``radius`` px on each true position."""
    folder.mkdir()
    for f in range(int(truth["frame"].max()) + 1):
        mask = np.zeros(shape, np.uint8)
        for r in truth[truth["frame"] == f]:
            cv2.circle(mask, (int(round(r["x"])), int(round(r["y"]))), radius, 255, -1)
        assert cv2.imwrite(str(folder / f"mask_{f}.png"), mask)      # natural order: 2 < 10


def test_a_folder_of_target_masks_is_truth(tmp_path, cli):
    """IRSTD datasets annotate targets as masks: each region of a mask is a target at its
    centroid, linked to the nearest of the frame before; evaluate and convert take the
    folder as --truth."""
    from irdetect.io.truth import read_mask_folder

    frames, truth = simulate("wan2008", rng=3, n_frames=36, height=48, width=64,
                             n_targets=2, snr=8.0, directions=[0.0, 180.0], dtype="uint8",
                             margin=6.0)
    _write_masks(tmp_path / "masks", truth, frames.shape[1:])
    got = read_mask_folder(tmp_path / "masks", 36)
    assert len(got) == len(truth) and len(np.unique(got["target"])) == 2
    for t in np.unique(got["target"]):            # each linked target is one true target
        rows = got[got["target"] == t]
        true = truth[(truth["frame"] == rows["frame"][0])]
        k = np.argmin(np.hypot(true["x"] - rows["x"][0], true["y"] - rows["y"][0]))
        want = truth[truth["target"] == true["target"][k]]
        np.testing.assert_allclose(rows["x"], np.round(want["x"]), atol=1e-6)
        np.testing.assert_allclose(rows["y"], np.round(want["y"]), atol=1e-6)
    write_sequence(tmp_path / "seq.h5", frames)
    assert cli("process", "seq.h5", "-o", "r.h5", "-q")[0] == 0
    code, out, err = cli("evaluate", "r.h5", "--truth", "masks", "--json")
    assert code == 0, err
    import json
    assert json.loads(out)["detection"]["targets"] == 6          # 2 targets x 3 windows
    code, _, err = cli("convert", "seq.h5", "-o", "with_truth.h5", "--truth", "masks")
    assert code == 0, err
    with open_sequence(tmp_path / "with_truth.h5") as src:
        for name in ("frame", "target", "x", "y"):
            np.testing.assert_array_equal(src.truth[name], got[name])
    # the count must match, and frames are not masks
    (tmp_path / "masks" / "mask_35.png").unlink()
    code, _, err = cli("evaluate", "r.h5", "--truth", "masks")
    assert code == 2 and "35 masks for 36 frames" in err
    (tmp_path / "frames").mkdir()
    for i, frame in enumerate(frames):
        cv2.imwrite(str(tmp_path / "frames" / f"{i}.png"), frame)
    code, _, err = cli("evaluate", "r.h5", "--truth", "frames")
    assert code == 2 and NO_TRUTH in err and "not a target mask" in err


def test_empty_masks_are_frames_without_a_target(tmp_path):
    from irdetect import tables
    from irdetect.io.truth import read_mask_folder

    (tmp_path / "m").mkdir()
    for f in range(3):
        cv2.imwrite(str(tmp_path / "m" / f"{f}.png"), np.zeros((8, 9), np.uint8))
    mask = np.zeros((8, 9), np.uint8)
    mask[3:5, 3:5] = 255                                    # a 2 x 2 px target
    cv2.imwrite(str(tmp_path / "m" / "3.png"), mask)
    got = read_mask_folder(tmp_path / "m", 4)
    assert got.dtype == tables.TRUTH and got[["frame", "target"]].tolist() == [(3, 0)]
    np.testing.assert_allclose([got["x"][0], got["y"][0]], [3.5, 3.5])
