import cv2
import h5py
import numpy as np
import pytest

from irdetect import tables
from irdetect.errors import InputError
from irdetect.io import (ResultsWriter, open_sequence, read_point_annotations, read_results,
                         write_sequence)


def _write_folder(folder, frames, ext=".png"):
    folder.mkdir()
    for i, frame in enumerate(frames):
        # unpadded names: natural sort must still put frame 2 before frame 10
        assert cv2.imwrite(str(folder / f"f{i}{ext}"), frame)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_every_reader_round_trips_the_same_frames(tmp_path, dtype):
    rng = np.random.default_rng(0)
    top = np.iinfo(dtype).max
    frames = rng.integers(0, top, size=(12, 17, 23), dtype=dtype)

    write_sequence(tmp_path / "a.h5", frames)
    np.save(tmp_path / "a.npy", frames)
    _write_folder(tmp_path / "png", frames)
    _write_folder(tmp_path / "tif", frames, ".tif")
    for path in ["a.h5", "a.npy", "png", "tif"]:
        with open_sequence(tmp_path / path) as src:
            assert src.shape == frames.shape and src.dtype == frames.dtype, path
            np.testing.assert_array_equal(src[:], frames, err_msg=path)
            np.testing.assert_array_equal(src[5], frames[5])
            got = np.concatenate([w for _, w in src.windows(5)])
            np.testing.assert_array_equal(got, frames)


@pytest.mark.parametrize("stored, read", [("i1", "f8"), ("u4", "f8"), ("i8", "f8"),
                                          ("u8", "f8"), ("f2", "f4")])
def test_other_pixel_types_are_read_widened_and_detect_alike(tmp_path, stored, read):
    # numpy's default integers (int64), 32-bit counts, int8 and float16: read as the type
    # the stages take, every value kept, and the same detections as the frames as uint8
    from irdetect.commands.info import describe
    from irdetect.config import ProcessConfig
    from irdetect.pipeline import detect_sequence
    from irdetect.simulate import simulate

    frames, _ = simulate("wan2008", snr=6, rng=3, n_frames=36, height=64, width=64)
    assert frames.dtype == np.uint8
    shifted = frames.astype(np.int16) - (128 if stored == "i1" else 0)
    data = shifted.astype(stored)
    with h5py.File(tmp_path / "a.h5", "w") as f:
        f["frames"] = data
    np.save(tmp_path / "a.npy", data)
    want = detect_sequence(frames, ProcessConfig())["detections"]
    for path in ["a.h5", "a.npy"]:
        with open_sequence(tmp_path / path) as src:
            assert src.dtype == np.dtype(read), path
            got = src[:]
            assert got.dtype == np.dtype(read)
            np.testing.assert_array_equal(got, shifted.astype(read))
            np.testing.assert_array_equal(src[7], shifted[7].astype(read))
            out = np.empty(got.shape, src.dtype)
            src.read_into(0, len(src), out)
            np.testing.assert_array_equal(out, got)
            det = detect_sequence(src, ProcessConfig())["detections"]
        assert len(want) and len(det) == len(want), path
        np.testing.assert_allclose(det["x"], want["x"], atol=1e-6, err_msg=path)
        np.testing.assert_allclose(det["y"], want["y"], atol=1e-6, err_msg=path)
        # `irdetect info` names both types
        assert f"{np.dtype(stored)} (read as {np.dtype(read)})" in describe(tmp_path / path)[1]


@pytest.mark.parametrize("dtype", [bool, np.complex64])
def test_pixels_that_are_no_numbers_are_refused(tmp_path, dtype):
    write = tmp_path / "a.npy"
    np.save(write, np.ones((12, 16, 16), dtype))
    with pytest.raises(InputError, match=f"unsupported pixel type {np.dtype(dtype)}"):
        open_sequence(write)


def test_video_reader_round_trips_lossless_frames(tmp_path):
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 255, size=(9, 32, 48), dtype=np.uint8)
    path = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, (48, 32), False)
    if not writer.isOpened():
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (48, 32), False)
        lossless = False
    else:
        lossless = True
    for frame in frames:
        writer.write(frame)
    writer.release()
    with open_sequence(path) as src:
        assert src.shape == frames.shape and src.dtype == np.uint8
        assert src.frame_rate == pytest.approx(10)
        got = src[:]
        if lossless:
            np.testing.assert_array_equal(got, frames)
        else:
            assert np.abs(got.astype(int) - frames).mean() < 40
        np.testing.assert_array_equal(src[4:6], got[4:6])


def test_hdf5_dataset_choice(tmp_path):
    path = tmp_path / "two.h5"
    with h5py.File(path, "w") as f:
        f["a/x"] = np.zeros((3, 4, 5), np.uint8)
        f["b"] = np.ones((2, 4, 5), np.float32)
    with pytest.raises(InputError, match="several 3-D datasets"):
        open_sequence(path)
    with open_sequence(path, dataset="b") as src:
        assert src.shape == (2, 4, 5)
    only = tmp_path / "one.h5"
    with h5py.File(only, "w") as f:
        f["movie"] = np.zeros((3, 4, 5), np.uint16)
    assert open_sequence(only).shape == (3, 4, 5)


def test_results_writer_is_atomic_and_keeps_empty_tables(tmp_path):
    out = tmp_path / "r.h5"
    with pytest.raises(RuntimeError):
        with ResultsWriter(out) as w:
            w.append("detections", tables.empty("detections"))
            raise RuntimeError("killed mid-run")
    assert not out.exists() and list(tmp_path.iterdir()) == []

    rows = tables.from_columns(tables.DETECTION, x=[1.5, 2.5], y=[3.0, 4.0])
    with ResultsWriter(out, attrs={"input": "seq.h5"}) as w:
        w.append("detections", rows[:1])
        w.append("detections", rows[1:])
        w.write("tracks", tables.empty("tracks"))
    res = read_results(out)
    np.testing.assert_array_equal(res["detections"]["x"], [1.5, 2.5])
    assert res["tracks"].dtype == tables.TRACK and len(res["tracks"]) == 0
    assert res.attrs["input"] == "seq.h5" and "irdetect_version" in res.attrs

    with pytest.raises(InputError, match="--force"):
        ResultsWriter(out)
    with ResultsWriter(out, force=True) as w:
        w.write("detections", rows[:1])
    assert len(read_results(out)["detections"]) == 1


def test_point_annotations(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text("1 2\n3.5 4.5\n\n# comment\n5 6\n")
    truth = read_point_annotations(path, 3)
    np.testing.assert_array_equal(truth["frame"], [0, 1, 2])
    np.testing.assert_array_equal(truth["x"], [1, 3.5, 5])
    with pytest.raises(InputError, match="3 annotation lines for 4 frames"):
        read_point_annotations(path, 4)
    path.write_text("1 2\nabc\n")
    with pytest.raises(InputError, match="line 2"):
        read_point_annotations(path)


def test_outputs_get_the_usual_permissions(tmp_path):
    import os
    import stat

    write_sequence(tmp_path / "a.h5", np.zeros((2, 3, 4), np.uint8))
    mode = stat.S_IMODE((tmp_path / "a.h5").stat().st_mode)
    mask = os.umask(0)
    os.umask(mask)
    assert mode == 0o666 & ~mask


def test_recording_folder_reads_its_frames_subfolder(tmp_path):
    frames = np.arange(3 * 4 * 5, dtype=np.uint8).reshape(3, 4, 5)
    _write_folder(tmp_path / "frames", frames)
    (tmp_path / "truth.txt").write_text("1 1\n2 2\n3 3\n")
    with open_sequence(tmp_path) as src:
        np.testing.assert_array_equal(src[:], frames)


def test_hdf5_read_ahead_is_a_chunk_only_when_compressed(tmp_path):
    # a compressed chunk is read whole (it is decompressed once per piece read); plain
    # chunks are read in pieces of at most PLAIN_BLOCK_BYTES, which bounds the streaming
    # reader's buffer for large frames
    from irdetect.io.sources import HDF5Source

    frames = np.zeros((80, 512, 640), np.uint16)
    for name, opts in (("plain.h5", {}), ("zip.h5", {"compression": "gzip"})):
        with h5py.File(tmp_path / name, "w") as f:
            f.create_dataset("frames", data=frames, chunks=(64, 512, 640), **opts)
    with open_sequence(tmp_path / "plain.h5") as plain, open_sequence(tmp_path / "zip.h5") as z:
        assert z.block_frames == 64
        assert plain.block_frames == HDF5Source.PLAIN_BLOCK_BYTES // (512 * 640 * 2) == 12
        np.testing.assert_array_equal(plain[70:80], z[70:80])


@pytest.mark.parametrize("fourcc, suffix, tag, lossy", [("FFV1", "avi", "ffv1", False),
                                                         ("mp4v", "mp4", "fmp4", True),
                                                         ("MJPG", "avi", "mjpg", True)])
def test_info_names_a_video_codec_and_whether_it_is_lossy(tmp_path, cli, fourcc, suffix, tag,
                                                          lossy):
    path = tmp_path / f"v.{suffix}"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10, (48, 32), False)
    if not writer.isOpened():
        pytest.skip(f"this OpenCV build writes no {fourcc}")
    for value in range(0, 90, 10):
        writer.write(np.full((32, 48), value, np.uint8))
    writer.release()
    with open_sequence(path) as src:
        assert src.codec == tag
    code, out, _ = cli("info", path)
    assert code == 0
    line = next(x for x in out.splitlines() if x.strip().startswith("codec"))
    assert line.split()[1].rstrip(":") == tag
    assert ("lossy" in line) == lossy
