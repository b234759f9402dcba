"""Multi-page TIFF and OME-TIFF stacks (tifffile): read lazily as stored, through
convert, info and process; a single page, a damaged file and a missing tifffile fail with
exit code 2 and one line."""

from __future__ import annotations

import builtins

import numpy as np
import pytest

from irdetect.errors import InputError
from irdetect.io import open_sequence, read_results

tifffile = pytest.importorskip("tifffile")


def _stack(dtype, shape=(9, 13, 17)):
    rng = np.random.default_rng(5)
    if np.dtype(dtype).kind == "f":
        return rng.normal(100, 10, shape).astype(dtype)
    return rng.integers(0, np.iinfo(dtype).max, shape, dtype=dtype)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
@pytest.mark.parametrize("kind", ["plain", "ome", "imagej"])
def test_tiff_stack_reads_as_stored(tmp_path, dtype, kind):
    frames = _stack(dtype)
    path = tmp_path / ("s.ome.tif" if kind == "ome" else "s.tif")
    if kind == "imagej":
        if dtype == np.float32:
            frames = frames.astype(np.float32)
        tifffile.imwrite(path, frames, imagej=True, metadata={"axes": "TYX", "finterval": 0.04})
    else:
        tifffile.imwrite(path, frames, ome=kind == "ome", metadata={"axes": "TYX"})
    with open_sequence(path) as src:
        assert type(src).__name__ == "TiffSource"
        assert src.shape == frames.shape and src.dtype == frames.dtype
        np.testing.assert_array_equal(src[:], frames)
        np.testing.assert_array_equal(src[4], frames[4])
        np.testing.assert_array_equal(np.concatenate([w for _, w in src.windows(4)]), frames)
        assert src.frame_rate == (pytest.approx(25.0) if kind == "imagej" else None)


def test_tiff_through_convert_info_and_process(tmp_path, cli):
    from irdetect.simulate import simulate

    frames, _ = simulate("wan2008", rng=2, n_frames=36, height=40, width=48, n_targets=1,
                         snr=6.0, directions=[30.0])
    tifffile.imwrite(tmp_path / "seq.tif", np.clip(frames, 0, 65535).astype(np.uint16))
    code, out, err = cli("info", "seq.tif")
    assert code == 0, err
    assert "36 frames of 48x40 px" in out and "uint16" in out
    code, _, err = cli("convert", "seq.tif", "-o", "seq.h5")
    assert code == 0, err
    with open_sequence(tmp_path / "seq.h5") as a, open_sequence(tmp_path / "seq.tif") as b:
        np.testing.assert_array_equal(a[:], b[:])
    code, _, err = cli("process", "seq.tif", "-o", "res.h5", "-q")
    assert code == 0, err
    assert read_results(tmp_path / "res.h5").attrs["n_frames"] == 36


@pytest.mark.parametrize("damage", ["half", "tail", "header"])
def test_damaged_tiff_is_one_line_and_exit_2(tmp_path, cli, damage):
    tifffile.imwrite(tmp_path / "s.tif", _stack(np.uint16))
    data = (tmp_path / "s.tif").read_bytes()
    bad = {"half": data[:len(data) // 2], "tail": data[:-100],
           "header": b"II*\x00" + b"garbage!" * 8}[damage]
    (tmp_path / "bad.tif").write_bytes(bad)
    for command in (["info", "bad.tif"], ["convert", "bad.tif", "-o", "x.h5"]):
        code, out, err = cli(*command)
        assert code == 2, (command, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "bad.tif" in lines[0] and "TIFF" in lines[0], err
    assert not (tmp_path / "x.h5").exists()


def test_single_page_tiff_is_not_a_sequence(tmp_path, cli):
    tifffile.imwrite(tmp_path / "one.tif", _stack(np.uint8)[0])
    code, _, err = cli("info", "one.tif")
    assert code == 2 and "single image is not a sequence" in err


def test_without_tifffile_the_error_says_what_to_install(tmp_path, monkeypatch):
    tifffile.imwrite(tmp_path / "s.tif", _stack(np.uint8))
    real_import = builtins.__import__

    def no_tifffile(name, *args, **kwargs):
        if name == "tifffile":
            raise ImportError("No module named 'tifffile'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_tifffile)
    with pytest.raises(InputError, match=r"pip install irdetect\[tiff\]"):
        open_sequence(tmp_path / "s.tif")


# --- compressed stacks (issue 29): OpenCV's imwritemulti writes LZW by default ------------

#: compression name -> (tifffile's compression argument, OpenCV's IMWRITE_TIFF_COMPRESSION)
COMPRESSIONS = {"none": (None, 1), "lzw": ("lzw", 5), "deflate": ("zlib", 8),
                "packbits": ("packbits", 32773)}


def _write_stack(path, frames, writer, compression):
    if writer == "opencv":
        import cv2
        assert cv2.imwritemulti(str(path), list(frames),
                                [cv2.IMWRITE_TIFF_COMPRESSION, COMPRESSIONS[compression][1]])
    else:
        pytest.importorskip("imagecodecs")     # tifffile encodes LZW and PackBits with it
        tifffile.imwrite(path, frames, compression=COMPRESSIONS[compression][0])


def _damage_strip(path, page=2):
    """Overwrite the strip data of one page (the file's structure stays intact)."""
    with tifffile.TiffFile(path) as tif:
        offset, count = tif.pages[page].dataoffsets[0], tif.pages[page].databytecounts[0]
    data = bytearray(path.read_bytes())
    data[offset + 4:offset + count] = b"\xab" * (count - 4)
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("compression", list(COMPRESSIONS))
@pytest.mark.parametrize("writer", ["opencv", "tifffile"])
def test_compressed_stack_reads_as_stored(tmp_path, cli, writer, compression):
    frames = _stack(np.uint16, (6, 40, 50))
    _write_stack(tmp_path / "s.tif", frames, writer, compression)
    with open_sequence(tmp_path / "s.tif") as src:
        assert src.shape == frames.shape and src.dtype == frames.dtype
        np.testing.assert_array_equal(src[:], frames)
        np.testing.assert_array_equal(src[3:5], frames[3:5])
    code, _, err = cli("convert", "s.tif", "-o", "s.h5", "-q")
    assert code == 0, err
    with open_sequence(tmp_path / "s.h5") as out:
        np.testing.assert_array_equal(out[:], frames)


@pytest.mark.parametrize("compression", ["lzw", "deflate", "packbits"])
def test_damaged_compressed_stack_says_corrupt(tmp_path, cli, compression):
    _write_stack(tmp_path / "s.tif", _stack(np.uint16, (6, 40, 50)), "opencv", compression)
    _damage_strip(tmp_path / "s.tif")
    code, _, err = cli("convert", "s.tif", "-o", "s.h5")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert "s.tif: corrupt or truncated TIFF file" in lines[0]
    assert not (tmp_path / "s.h5").exists()


#: run in a Python without imagecodecs (an import of it fails): read every stack given,
#: compare with the .npy beside it, print one result line per file
_WITHOUT_IMAGECODECS = """
import sys
sys.modules["imagecodecs"] = None
import numpy as np
from irdetect.errors import InputError
from irdetect.io import open_sequence
for name in sys.argv[1:]:
    try:
        with open_sequence(name + ".tif") as src:
            same = np.array_equal(src[:], np.load(name + ".npy"))
            print(name, "opencv" if src._opencv else "tifffile", same)
    except InputError as exc:
        print(name, "error", exc)
"""


def test_without_imagecodecs_opencv_reads_what_tifffile_cannot(tmp_path):
    """The `tiff` extra brings imagecodecs; a tifffile without it still reads OpenCV's
    LZW (OpenCV decodes it), says corrupt for a damaged one and names the package for a
    compression neither decodes."""
    import subprocess
    import sys

    frames = _stack(np.uint16, (6, 40, 50))
    names = []
    for writer in ("opencv", "tifffile"):
        for compression in COMPRESSIONS:
            name = f"{writer}-{compression}"
            _write_stack(tmp_path / f"{name}.tif", frames, writer, compression)
            np.save(tmp_path / f"{name}.npy", frames)
            names.append(name)
    _write_stack(tmp_path / "bad.tif", frames, "opencv", "lzw")
    _damage_strip(tmp_path / "bad.tif")
    pytest.importorskip("imagecodecs")
    tifffile.imwrite(tmp_path / "zstd.tif", frames, compression="zstd")
    for extra in ("bad", "zstd"):
        np.save(tmp_path / f"{extra}.npy", frames)
    run = subprocess.run([sys.executable, "-c", _WITHOUT_IMAGECODECS, *names, "bad", "zstd"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stderr == ""                        # OpenCV's libtiff log stays quiet
    found = dict(line.split(" ", 1) for line in run.stdout.strip().splitlines())
    for name in names:
        reader = "opencv" if name.endswith("lzw") else "tifffile"
        assert found[name] == f"{reader} True", (name, found[name])
    assert found["bad"].startswith("error bad.tif: corrupt or truncated TIFF file")
    assert found["zstd"] == ("error zstd.tif: ZSTD compressed TIFF pages need the imagecodecs "
                             "package: pip install imagecodecs (or irdetect[tiff])")
