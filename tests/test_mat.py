"""MATLAB MAT-files: a variable of H x W x T (frame k = seq(:,:,k)) read as (T, H, W) from
version 7.3 (HDF5, axes reversed on disk) and from older versions (scipy.io.loadmat);
through info, convert and process; a file without one such variable fails with exit
code 2 and one line."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from scipy.io import savemat

from irdetect.io import open_sequence, read_results


def _matlab_stack(shape=(13, 17, 9), dtype=np.uint16, seed=5) -> np.ndarray:
    """A MATLAB-ordered stack: H x W x T (rows, columns, frames), not square so that a
    transposed frame cannot pass for the right one."""
    return np.random.default_rng(seed).integers(0, 4000, shape).astype(dtype)


def _write_v73(path, variables: dict) -> None:
    """Write ``variables`` as MATLAB's ``save -v7.3`` does: an HDF5 file behind a 512-byte
    header (its text, then version and endian bytes), each array stored column-major
    (HDF5 sees its axes reversed) with its MATLAB_class attribute."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            d = f.create_dataset(name, data=np.asarray(value).T, chunks=True)
            d.attrs["MATLAB_class"] = np.bytes_({np.dtype(np.float64): "double"}.get(
                np.dtype(value.dtype), np.dtype(value.dtype).name))
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Sun Dec  6 12:00:00 2026 HDF5 schema 1.00 ."
    with open(path, "r+b") as f:
        f.write(header.ljust(116) + b"\x00" * 8 + b"\x00\x02IM")


@pytest.mark.parametrize("version", ["7.3", "5"])
def test_a_matlab_stack_reads_frame_by_frame(tmp_path, version):
    seq = _matlab_stack()
    path = tmp_path / "seq.mat"
    if version == "7.3":
        _write_v73(path, {"seq": seq, "note": np.arange(4.0)})
    else:
        savemat(path, {"seq": seq, "note": np.arange(4.0)})
    with open_sequence(path) as src:
        assert src.shape == (9, 13, 17) and src.dtype == np.uint16
        for k in (0, 4, 8):                               # frame k is seq(:,:,k)
            np.testing.assert_array_equal(src[k], seq[:, :, k])
        np.testing.assert_array_equal(src[2:5], np.moveaxis(seq, 2, 0)[2:5])
        out = np.empty((3, 13, 17), np.uint16)
        src.read_into(5, 8, out)
        np.testing.assert_array_equal(out, np.moveaxis(seq, 2, 0)[5:8])


@pytest.mark.parametrize("version", ["7.3", "5"])
def test_matlab_variables_are_chosen_or_refused_by_name(tmp_path, cli, version):
    a, b = _matlab_stack(seed=1), _matlab_stack(seed=2)
    path = tmp_path / "two.mat"
    if version == "7.3":
        _write_v73(path, {"a": a, "b": b})
    else:
        savemat(path, {"a": a, "b": b})
    with open_sequence(path, dataset="b") as src:
        np.testing.assert_array_equal(src[3], b[:, :, 3])
    code, _, err = cli("info", "two.mat")
    assert code == 2 and "several 3-D variables (a, b)" in err and "--dataset" in err
    assert len(err.strip().splitlines()) == 1
    if version == "5":
        savemat(tmp_path / "flat.mat", {"image": a[:, :, 0]})
    else:
        _write_v73(tmp_path / "flat.mat", {"image": a[:, :, 0]})
    code, _, err = cli("info", "flat.mat")
    assert code == 2 and "no 3-D numeric variable" in err and "flat.mat" in err


def test_a_damaged_mat_file_is_one_line_and_exit_2(tmp_path, cli):
    (tmp_path / "bad.mat").write_bytes(b"MATLAB 5.0 MAT-file" + b"\x00" * 40)
    code, _, err = cli("info", "bad.mat")
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "bad.mat" in lines[0] and "MAT-file" in lines[0], err


def test_a_matlab_sequence_through_info_convert_and_process(tmp_path, cli):
    from irdetect.simulate import simulate

    frames, truth = simulate("wan2008", rng=2, n_frames=36, height=40, width=48,
                             n_targets=1, snr=8.0, directions=[30.0])
    seq = np.moveaxis(np.clip(frames, 0, 65535).astype(np.uint16), 0, 2)      # H x W x T
    _write_v73(tmp_path / "seq.mat", {"seq": seq})
    code, out, err = cli("info", "seq.mat")
    assert code == 0, err
    assert "36 frames of 48x40 px" in out
    code, _, err = cli("convert", "seq.mat", "-o", "seq.h5")
    assert code == 0, err
    with open_sequence(tmp_path / "seq.h5") as h5:
        np.testing.assert_array_equal(h5[:], np.moveaxis(seq, 2, 0))
    code, _, err = cli("process", "seq.mat", "-o", "res.h5", "-q")
    assert code == 0, err
    det = read_results(tmp_path / "res.h5")["detections"]
    # x = column, y = row as in the simulator's truth: the frames were not transposed
    t = (det["frame_start"] + det["frame_end"]) // 2
    assert len(det) and np.all(np.hypot(det["x"] - truth["x"][t], det["y"] - truth["y"][t]) < 3)


def test_a_folder_of_mat_files_is_a_folder_of_sequences(tmp_path):
    from irdetect.batch import expand_inputs

    for name in ("b.mat", "a.mat"):
        savemat(tmp_path / name, {"seq": _matlab_stack()})
    assert [p.name for p in expand_inputs([tmp_path])] == ["a.mat", "b.mat"]
