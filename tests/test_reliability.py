"""The promise on bad input and faults (docs/reliability.md), case by case.

Every case ends with exit 0 and a valid result, or exit 2 and one line naming the problem
(and the file, when there is one): no traceback, the inputs unchanged, nothing left at
the output path or beside it. The cases are those of issue 18 (249 tried, 43 broke the
promise), then randomised readers (hypothesis; ``scripts/fuzz`` runs many more examples).
Signals, disk full, FIFOs and concurrent writers run the CLI in a child process.
"""

from __future__ import annotations

import hashlib
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from irdetect.errors import InputError
from irdetect.io import open_sequence, read_results, write_sequence

settings.register_profile("nightly", max_examples=1000, deadline=None)
settings.register_profile("ci", max_examples=25, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.function_scoped_fixture])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


# --- fixtures and the promise -------------------------------------------------------------

def _sequence(path: Path, n_frames: int = 36, size=(64, 64), seed: int = 1) -> Path:
    from irdetect.simulate import simulate

    frames, truth = simulate("wan2008", rng=seed, n_frames=n_frames, height=size[1],
                             width=size[0], n_targets=1, directions=(30.0,),
                             speed=[36 / n_frames] * 2)
    write_sequence(path, frames, truth=truth, attrs={"frame_rate": 25.0})
    return path


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A sequence and its results, made once: (folder, seq.h5, res.h5)."""
    from irdetect.pipeline import process_file

    folder = tmp_path_factory.mktemp("made")
    seq = _sequence(folder / "seq.h5")
    process_file(seq, folder / "res.h5")
    return folder, seq, folder / "res.h5"


@pytest.fixture
def work(made, tmp_path, monkeypatch):
    """A fresh folder holding copies of seq.h5 and res.h5; the CLI runs in it."""
    folder, seq, res = made
    for p in (seq, res):
        (tmp_path / p.name).write_bytes(p.read_bytes())
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "-"


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def promise(code: int, err: str, folder: Path, *, want=(0, 2), names=None, before=None):
    """Assert the promise of one run: its exit code is one of ``want``; on exit 2, one
    line that names ``names`` (a file or an option); no traceback; nothing hidden left in
    ``folder``; the files of ``before`` ({path: digest}) unchanged."""
    assert code in want, (code, err)
    assert "Traceback" not in err and "Exception" not in err, err
    if code == 2:
        lines = err.strip().splitlines()
        assert lines and lines[-1].startswith("irdetect"), err
        assert " error: " in lines[-1], err
        if names:
            assert names in lines[-1], err
    assert _hidden(folder) == [], _hidden(folder)
    for path, digest in (before or {}).items():
        assert _digest(path) == digest, f"{path} changed"


@pytest.fixture
def run(work, capsys):
    """Run the CLI in-process in ``work``: returns (code, stderr) after checking that the
    inputs seq.h5 and res.h5 are unchanged and nothing hidden is left."""
    from irdetect.cli import main

    def call(*argv, want=(0, 2), names=None):
        before = {p: _digest(p) for p in (work / "seq.h5", work / "res.h5")}
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:       # argparse's own errors
            code = exc.code
        err = capsys.readouterr().err
        promise(code, err, work, want=want, names=names, before=before)
        return code, err

    return call


def child(*argv, cwd, timeout=120, limit_bytes=None, **kw):
    """Start the CLI in a child process (``python -m irdetect``)."""
    def limit():
        if limit_bytes is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return subprocess.Popen([sys.executable, "-m", "irdetect", *map(str, argv)], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=limit, **kw)


def finish(proc, timeout=120):
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, err


# --- tracebacks -----------------------------------------------------------------------------

@pytest.mark.parametrize("size", [(100, 100), (213, 252)])
def test_odd_tile_sizes_process(work, run, size):
    _sequence(work / "odd.h5", size=size)
    code, _ = run("process", "odd.h5", "-o", "odd.out.h5", "-q", want=(0,))
    assert "detections" in read_results(work / "odd.out.h5")


@pytest.mark.parametrize("name", ["seq.h5", "res.h5"])
def test_info_on_truncated_files(work, run, name):
    data = (work / name).read_bytes()
    (work / "cut.h5").write_bytes(data[:len(data) // 2])
    run("info", "cut.h5", want=(2,), names="cut.h5")


@pytest.mark.parametrize("value", [np.array([1.0, 2.0]), "fast", -5.0, np.nan])
def test_bad_frame_rate_attribute(work, run, value):
    with h5py.File(work / "seq.h5", "a") as f:
        f.attrs["frame_rate"] = value
    run("process", "seq.h5", "-o", "o.h5", want=(2,), names="frame_rate")
    assert not (work / "o.h5").exists()


def test_config_that_is_a_folder(work, run):
    (work / "conf").mkdir()
    run("process", "seq.h5", "-o", "o.h5", "--config", "conf", want=(2,), names="conf")


@pytest.mark.parametrize("text, names", [
    ("[combine]\nlength = 1000000000\n", "combine.length"),
    ("[initiate]\nrho_step = 1e-9\n", "rho_step"),
])
def test_absurd_settings_refused_before_work(work, run, text, names):
    (work / "bad.toml").write_text(text)
    t = time.perf_counter()
    _, err = run("process", "seq.h5", "-o", "o.h5", "--config", "bad.toml", want=(2,),
                 names=names)
    assert "bad.toml" in err and not (work / "o.h5").exists()
    assert time.perf_counter() - t < 30          # refused up front, not after the run


def _scans(work: Path, *, shift=0, nan_truth=False) -> Path:
    from irdetect.io.scans import write_scans
    from irdetect.simulate.scans import simulate_scans

    scans, truth, attrs = simulate_scans("zhang2010", rng=2, n_scans=6)
    scans["scan"] += shift
    truth["scan"] += shift
    if nan_truth:
        truth["x"][3] = np.nan
    path = work / "scans.h5"
    write_scans(path, scans, truth=truth, attrs=attrs, force=True)
    return path


def test_scan_numbers_near_1e15(work, run):
    _scans(work, shift=10 ** 15)
    run("initiate", "scans.h5", "-o", "t.h5")


def test_evaluate_scans_with_nan_truth(work, run):
    _scans(work, nan_truth=True)
    code, _ = run("initiate", "scans.h5", "-o", "t.h5")
    if code == 0:
        run("evaluate", "t.h5", "--truth", "scans.h5")


def test_evaluate_config_not_json(work, run):
    with h5py.File(work / "res.h5", "a") as f:
        f.attrs["config"] = "{not json"
    run("evaluate", "res.h5", "--truth", "seq.h5", want=(2,), names="config")


def test_evaluate_detections_missing_a_field(work, run):
    import numpy.lib.recfunctions as rf

    with h5py.File(work / "res.h5", "a") as f:
        rows = f["detections"][()]
        del f["detections"]
        f["detections"] = rf.drop_fields(rows, ["x"])
    run("evaluate", "res.h5", "--truth", "seq.h5", want=(2,), names="res.h5")


def test_output_where_nothing_can_be_written(work, run):
    if os.geteuid() == 0:
        target = "/sys/irdetect-test.h5"          # root writes through chmod; not here
    else:
        (work / "ro").mkdir(mode=0o555)
        target = "ro/o.h5"
    run("process", "seq.h5", "-o", target, want=(2,), names=target)


@pytest.mark.parametrize("argv, names", [
    (["simulate", "h.h5", "--size", "200000x200000"], "200000x200000"),
    (["simulate", "h.h5", "--snr", "nan"], "--snr"),
    (["simulate", "h.h5", "--speed", "1", "inf"], "--speed"),
    (["simulate-scans", "h.h5", "--clutter-density", "nan"], "--clutter-density"),
    (["simulate-scans", "h.h5", "--clutter-density", "1e9"], "clutter points"),
    (["plot", "res.h5", "-o", "p.png", "--scale", "0"], "--scale"),
    (["convert", "seq.h5", "-o", "c.h5", "--frame-rate", "nan"], "--frame-rate"),
    (["convert", "seq.h5", "-o", "c.h5", "--frame-rate", "-25"], "--frame-rate"),
    (["video", "seq.h5", "res.h5", "-o", "v.mp4", "--percentiles", "90", "10"],
     "--percentiles"),
    (["simulate", "h.h5", "--size", "0x0"], "height"),
])
def test_bad_option_values(work, run, argv, names):
    _, err = run(*argv, want=(2,), names=names)
    assert "presets" not in err                 # an option's fault, not the preset file's
    assert not any((work / n).exists() for n in ("h.h5", "p.png", "c.h5", "v.mp4"))


def test_broken_pipe(work):
    proc = subprocess.run(f"{sys.executable} -m irdetect evaluate res.h5 --truth seq.h5 "
                          "| head -1", shell=True, cwd=work, capture_output=True, text=True,
                          timeout=120)
    assert proc.stdout.strip() and "Traceback" not in proc.stderr and not proc.stderr.strip()


@pytest.mark.parametrize("argv", [["convert", "seq.h5", "-o", "full.h5"],
                                  ["process", "seq.h5", "-o", "full.h5"],
                                  ["simulate", "full.h5", "--frames", "36"]])
def test_disk_full(work, argv):
    code, err = finish(child(*argv, "-q", cwd=work, limit_bytes=50_000))
    promise(code, err, work, want=(2,), names="full.h5")
    assert "file size limit" in err and not (work / "full.h5").exists()


# --- signals, kills and concurrent runs ----------------------------------------------------

@pytest.fixture(scope="module")
def long_seq(made):
    """A sequence that takes a few seconds to process."""
    folder = made[0]
    path = folder / "long.h5"
    if not path.exists():
        _sequence(path, n_frames=720, size=(160, 128), seed=5)
    return path


def _started(proc, folder: Path, name: str, wait: float = 60.0) -> None:
    """Wait until the child holds the output's lock (its work has begun)."""
    lock = folder / f".{name}.irdetect-lock"
    t = time.time()
    while not lock.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.time() - t < wait
        time.sleep(0.02)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("command", ["process", "convert", "video"])
def test_signals_leave_nothing(work, long_seq, sig, command):
    from irdetect.pipeline import process_file

    if command == "video":
        process_file(long_seq, work / "long.res.h5")
        argv, name = ["video", long_seq, "long.res.h5", "-o", "v.avi"], "v.avi"
    else:
        argv, name = [command, long_seq, "-o", "out.h5"], "out.h5"
    delay = np.random.default_rng().uniform(0.0, 0.4)      # any time during the write
    proc = child(*argv, "-q", cwd=work)
    _started(proc, work, name)
    time.sleep(delay)
    proc.send_signal(sig)
    code, err = finish(proc)
    note = f"(signal {delay:.3f} s after the lock)"
    if code in (0, -sig):   # it had finished (-sig: after the CLI returned): a whole output
        assert (work / name).exists()
        if name.endswith(".h5"):
            _read_whole(work / name, command)
    else:
        assert code == 128 + sig, (err, note)
        assert err.strip().splitlines()[-1].endswith(("interrupted", "terminated")), note
        if (work / name).exists() and name.endswith(".h5"):   # committed just before
            _read_whole(work / name, command)
    promise(0, err, work)


def _read_whole(path, command):
    """Read an output through: the results of process, or the sequence convert wrote."""
    if command == "convert":
        with open_sequence(path) as src:
            assert src[:].shape == src.shape
    else:
        read_results(path)


def test_kill_9_leftovers_removed_by_the_next_run(work, long_seq, run):
    proc = child("process", long_seq, "-o", "out.h5", "-q", cwd=work)
    _started(proc, work, "out.h5")
    time.sleep(0.5)
    proc.kill()
    proc.communicate()
    assert _hidden(work) and not (work / "out.h5").exists()      # a dead run's files
    run("process", "seq.h5", "-o", "out.h5", "-q", want=(0,))       # ... removed now
    assert "detections" in read_results(work / "out.h5")


def test_second_writer_to_the_same_output_fails(work, long_seq, capsys):
    from irdetect.cli import main

    proc = child("process", long_seq, "-o", "out.h5", "-q", cwd=work)
    _started(proc, work, "out.h5")
    for force in ([], ["--force"]):
        code = main(["process", "seq.h5", "-o", "out.h5", "-q", *force])
        err = capsys.readouterr().err
        assert code == 2 and "another irdetect run is writing" in err, err
    code, err = finish(proc)
    assert code == 0, err
    promise(code, err, work)
    assert read_results(work / "out.h5").attrs["n_frames"] == 720     # the first run's


def test_output_appearing_during_a_run_is_not_replaced(work):
    from irdetect.io import atomic_output

    with pytest.raises(InputError, match="appeared during the run"):
        with atomic_output(work / "x.txt") as tmp:
            Path(tmp).write_text("new")
            (work / "x.txt").write_text("someone else's")
    assert (work / "x.txt").read_text() == "someone else's" and _hidden(work) == []


# --- silent wrong results --------------------------------------------------------------------

@pytest.mark.parametrize("how", ["same", "symlink", "hardlink", "dotted"])
def test_output_is_never_the_input(work, run, how):
    out = {"same": "seq.h5", "symlink": "link.h5", "hardlink": "hard.h5",
           "dotted": "./sub/../seq.h5"}[how]
    (work / "sub").mkdir()
    if how == "symlink":
        os.symlink("seq.h5", work / "link.h5")
    if how == "hardlink":
        os.link(work / "seq.h5", work / "hard.h5")
    run("process", "seq.h5", "-o", out, "--force", want=(2,), names="is the input")
    run("convert", "seq.h5", "-o", out, "--force", want=(2,), names="is the input")
    with h5py.File(work / "seq.h5") as f:
        assert "frames" in f


def test_annotation_lines_must_match_the_frames(work, run):
    rec = work / "rec"
    (rec / "frames").mkdir(parents=True)
    import cv2
    with open_sequence(work / "seq.h5") as src:
        for i in range(len(src)):
            cv2.imwrite(str(rec / "frames" / f"{i:03d}.png"), src[i])
    (rec / "truth.txt").write_text("1 2\n3 4\n")
    run("process", "rec", "-o", "rec.h5", "-q", want=(0,))
    run("evaluate", "rec.h5", "--truth", "rec/truth.txt", want=(2,), names="2 annotation")


def test_outputs_have_the_usual_mode(work, run):
    run("plot", "res.h5", "-o", "p.png", want=(0,))
    run("convert", "seq.h5", "-o", "c.h5", "-q", want=(0,))
    umask = os.umask(0)
    os.umask(umask)
    for name in ("p.png", "c.h5"):
        assert os.stat(work / name).st_mode & 0o777 == 0o666 & ~umask


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_process_refuses_nan_frames(work, run, bad):
    with open_sequence(work / "seq.h5") as src:
        frames = src[:].astype(np.float32)
    frames[20, 5, 5] = bad
    write_sequence(work / "nan.h5", frames)
    run("process", "nan.h5", "-o", "o.h5", want=(2,), names="NaN or inf")
    assert not (work / "o.h5").exists()


# --- hangs -------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv", [["info", "x.h5"], ["process", "x.h5", "-o", "y.h5"],
                                  ["convert", "x.h5", "-o", "y.h5"],
                                  ["evaluate", "res.h5", "--truth", "x.h5"],
                                  ["process", "seq.h5", "-o", "y.h5", "--config", "x.h5"]])
def test_fifo_is_refused_not_waited_on(work, argv):
    os.mkfifo(work / "x.h5")
    code, err = finish(child(*argv, cwd=work), timeout=60)
    promise(code, err, work, want=(2,), names="not a regular file")


def test_tiny_frames_refused(work, run):
    write_sequence(work / "tiny.h5", np.random.default_rng(0).normal(100, 2, (60, 2, 2))
                   .astype(np.float32))
    run("process", "tiny.h5", "-o", "o.h5", want=(2,), names="too small")
    run("track", "tiny.h5", "-o", "o.h5", want=(2,), names="too small")
    assert not (work / "o.h5").exists()


# --- unclear messages -------------------------------------------------------------------------

@pytest.mark.parametrize("folder", ["empty", "x.h5"])
def test_folders_without_sequences_are_named(work, run, folder):
    (work / folder).mkdir()
    run("process", folder, want=(2,), names=f"{folder}: folder holds no sequence")


def test_library_log_lines_stay_off_stderr(work):
    (work / "junk.mp4").write_bytes(np.random.default_rng(0).bytes(50_000))
    code, err = finish(child("info", "junk.mp4", cwd=work))
    assert code == 2 and len(err.strip().splitlines()) == 1, err


def test_a_missing_frame_number_is_named(work):
    import cv2
    (work / "pngs").mkdir()
    for i in [*range(20), *range(21, 40)]:
        cv2.imwrite(str(work / "pngs" / f"f{i:03d}.png"), np.full((32, 32), i, np.uint8))
    code, err = finish(child("info", "pngs", cwd=work))
    assert code == 0 and "frame numbers skip at f019.png -> f021.png (1 place)" in err, err


def test_damaged_image_in_a_folder_is_one_line(work):
    import cv2
    (work / "pngs").mkdir()
    for i in range(40):
        cv2.imwrite(str(work / "pngs" / f"{i:03d}.png"), np.full((32, 32), i, np.uint8))
    (work / "pngs" / "010.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"junk" * 10)
    code, err = finish(child("process", "pngs", "-o", "o.h5", cwd=work))
    # OpenCV's decoder logs its own line ("IHDR chunk shall be first") unless -v
    assert code == 2 and err.strip().splitlines() == [
        "irdetect process: error: pngs/010.png: cannot read this image"], err
    assert not (work / "o.h5").exists()


def test_argparse_errors_are_one_line(work):
    code, err = finish(child("process", "seq.h5", "--bogus", cwd=work))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--bogus" in err, err


# --- randomised readers ------------------------------------------------------------------------

DTYPES = ["u1", "u2", "i2", "i4", "f4", "f8", "i8", "u4", "f2", "b1", "c8"]


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(shape=st.lists(st.integers(0, 9), min_size=0, max_size=4),
       dtype=st.sampled_from(DTYPES),
       rate=st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True),
                      st.text(st.characters(blacklist_characters="\x00"), max_size=3),
                      st.lists(st.floats(0, 9), max_size=3)))
def test_random_hdf5_sequences(tmp_path, shape, dtype, rate):
    path = tmp_path / "r.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("frames", data=np.ones(shape, dtype))
        if rate is not None:
            f.attrs["frame_rate"] = rate
    try:
        with open_sequence(path) as src:
            assert src[:].shape == tuple(shape)
    except InputError as exc:
        assert str(exc).startswith(str(path))


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fraction=st.floats(0.0, 0.999), which=st.sampled_from(["seq.h5", "res.h5"]))
def test_truncated_files_at_random_offsets(made, tmp_path, fraction, which):
    from irdetect.commands.info import describe

    data = (made[0] / which).read_bytes()
    path = tmp_path / "cut.h5"
    path.write_bytes(data[:int(len(data) * fraction)])
    for reader in (describe, read_results, lambda p: open_sequence(p)[:]):
        try:
            reader(path)
        except InputError as exc:
            assert str(exc).startswith(str(path))


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=400),
       suffix=st.sampled_from([".npy", ".h5", ".mp4", ".toml", ".mat"]))
def test_random_bytes(tmp_path, data, suffix):
    from irdetect.config import load_config

    path = tmp_path / f"r{suffix}"
    path.write_bytes(data)
    try:
        if suffix == ".toml":
            load_config(path)
        else:
            with open_sequence(path) as src:
                src[:]
    except InputError as exc:
        assert str(exc).startswith(str(path))


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(stage=st.sampled_from(["combine", "detect", "fuse", "correlate", "initiate"]),
       value=st.one_of(st.integers(-10, 10 ** 12), st.floats(allow_nan=False),
                       st.text(max_size=4), st.booleans()))
def test_random_config_values(tmp_path, stage, value):
    """Any value of any field is accepted or refused with an InputError before a run."""
    import dataclasses
    import tomllib

    from irdetect.config import ProcessConfig, load_config
    from irdetect.pipeline import check_config

    fields = [f.name for f in dataclasses.fields(getattr(ProcessConfig(), stage))]
    path = tmp_path / "c.toml"
    for name in fields[:4]:
        literal = repr(value).lower() if isinstance(value, bool) else repr(value)
        if isinstance(value, str):
            literal = '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
        text = f"[{stage}]\n{name} = {literal}\n"
        try:
            tomllib.loads(text)
        except tomllib.TOMLDecodeError:
            continue
        path.write_text(text)
        try:
            check_config(load_config(path), path, frame_shape=(64, 64))
        except InputError:
            pass


def test_initiate_refuses_a_window_of_a_million_points(work, run):
    """1e6 clutter points ran past 900 s at 5.5 GB: refused up front, with the reason."""
    from irdetect import tables
    from irdetect.io.scans import write_scans

    r = np.random.default_rng(0)
    scan = np.sort(r.integers(0, 10, 1_000_000))
    rows = tables.from_columns(tables.SCAN, scan=scan, time=scan * 5.0,
                               x=r.uniform(0, 1e5, scan.size), y=r.uniform(0, 1e5, scan.size))
    write_scans(work / "dense.h5", rows, attrs={"sigma": 100.0, "speed_min": 30.0,
                                                 "speed_max": 350.0, "period": 5.0})
    t = time.perf_counter()
    run("initiate", "dense.h5", "-o", "t.h5", want=(2,), names="measurements")
    assert time.perf_counter() - t < 60 and not (work / "t.h5").exists()


def test_a_dead_runs_leftovers_beside_a_committed_output_are_removed(work, run, capsys):
    """A run killed after its commit (output in place) but before it removed its lock and
    temporary: the next run refuses the output (exit 2) and clears them, unless a live
    run holds the lock."""
    import fcntl

    from irdetect.cli import main

    run("convert", "seq.h5", "-o", "out.h5", "-q", want=(0,))
    lock, tmp = work / ".out.h5.irdetect-lock", work / ".out.h5.irdetect-k1ll.tmp"
    for live in (True, False):
        lock.write_bytes(b"")
        tmp.write_bytes(b"partial")
        fd = os.open(lock, os.O_RDWR)
        if live:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        try:
            assert main(["convert", "seq.h5", "-o", "out.h5", "-q"]) == 2
        finally:
            os.close(fd)
        assert "output exists" in capsys.readouterr().err
        assert _hidden(work) == (sorted([lock.name, tmp.name]) if live else [])
