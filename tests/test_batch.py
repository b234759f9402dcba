"""Batch processing: inputs, resume, failures, local processes and a real Dask LocalCluster.

The scenes are tiny simulated sequences (80 x 80 x 48, bright slow targets) so the whole file
stays within its time budget; the cluster is one 2-worker ``distributed.LocalCluster`` on
loopback shared by the Dask tests.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from irdetect.batch import (RESULTS_SUFFIX, SUMMARY_NAME, expand_inputs, fingerprint,
                            imap_tasks, map_tasks, run_batch)
from irdetect.errors import InputError
from irdetect.io import open_sequence, read_results, write_sequence
from irdetect.pipeline import detect_sequence
from irdetect.simulate import simulate

TABLES = ("candidates", "detections", "segments", "tracks")
SCENE = dict(height=80, width=80, n_frames=48, n_targets=2, directions=(0.0, 90.0), snr=6.0,
             speed=(0.5, 0.5))


def _simulate(path: Path, seed: int, **overrides) -> np.ndarray:
    frames, truth = simulate("wan2008", rng=seed, **{**SCENE, **overrides})
    write_sequence(path, frames, truth=truth, attrs={"frame_rate": 25.0}, force=True)
    return truth


@pytest.fixture(scope="module")
def seqdir(tmp_path_factory):
    """A folder of 4 simulated sequences: (folder, {name: truth})."""
    folder = tmp_path_factory.mktemp("seqs")
    truths = {f"seq{i}": _simulate(folder / f"seq{i}.h5", seed=10 + i) for i in range(4)}
    return folder, truths


@pytest.fixture(scope="module")
def reference(seqdir, tmp_path_factory):
    """The batch run with jobs=1 (in this process): (report, {name: tables})."""
    out = tmp_path_factory.mktemp("ref")
    report = run_batch([seqdir[0]], out, jobs=1)
    return report, _tables(out)


def _tables(out_dir: Path) -> dict[str, dict[str, bytes]]:
    """Every results table of a folder, as raw bytes (byte-for-byte comparison)."""
    found = {}
    for path in sorted(out_dir.glob("*" + RESULTS_SUFFIX)):
        res = read_results(path)
        found[path.name[:-len(RESULTS_SUFFIX)]] = {
            name: (res[name].dtype.descr, res[name].tobytes()) for name in TABLES}
    return found


def _summary(out_dir: Path) -> list[dict]:
    with open(out_dir / f"{SUMMARY_NAME}.csv", newline="") as fh:
        return list(csv.DictReader(fh))


# --- inputs ---------------------------------------------------------------------------

def test_expand_inputs_files_folders_globs(tmp_path):
    seqs = tmp_path / "data"
    seqs.mkdir()
    _simulate(seqs / "b.h5", seed=1)
    np.save(seqs / "a10.npy", np.zeros((3, 4, 4), np.uint8))
    np.save(seqs / "a9.npy", np.zeros((3, 4, 4), np.uint8))
    (seqs / "frames").mkdir()
    for i in range(3):
        cv2.imwrite(str(seqs / "frames" / f"f{i}.png"), np.full((8, 8), i, np.uint8))
    (seqs / "notes.txt").write_text("not a sequence")
    (seqs / "b.irdetect.h5").write_bytes(b"")           # a results file is never an input
    (seqs / ".b.h5.tmp").write_bytes(b"")

    found = expand_inputs([seqs])
    assert [p.name for p in found] == ["a9.npy", "a10.npy", "b.h5", "frames"]   # natural order
    assert expand_inputs([seqs / "frames"]) == [seqs / "frames"]     # images: one sequence
    assert [p.name for p in expand_inputs([str(seqs / "*.h5")])] == ["b.h5"]
    # duplicates collapse, order of the arguments is kept
    assert [p.name for p in expand_inputs([seqs / "b.h5", seqs, seqs / "b.h5"])] == [
        "b.h5", "a9.npy", "a10.npy", "frames"]
    with pytest.raises(InputError, match="file not found"):
        expand_inputs([tmp_path / "missing.h5"])
    with pytest.raises(InputError, match="no file matches"):
        expand_inputs([str(tmp_path / "*.hdf5")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="holds no sequence"):
        expand_inputs([tmp_path / "empty"])


def test_same_results_name_is_refused(tmp_path):
    for sub in ("a", "b"):
        (tmp_path / sub).mkdir()
        _simulate(tmp_path / sub / "seq.h5", seed=2)
    with pytest.raises(InputError, match="would both write seq.irdetect.h5") as err:
        run_batch([tmp_path / "a" / "seq.h5", tmp_path / "b" / "seq.h5"], tmp_path / "out",
                  jobs=1)
    assert "recording folders" not in str(err.value)
    # recordings laid out as NAME/frames/ (frames and truth.txt): their folders are the
    # inputs to give, and they are processed under their own names
    frames, _ = simulate("wan2008", rng=3, n_frames=36, height=40, width=48, n_targets=1)
    for sub in ("rec1", "rec2"):
        (tmp_path / sub / "frames").mkdir(parents=True)
        for i, f in enumerate(frames):
            cv2.imwrite(str(tmp_path / sub / "frames" / f"{i:03d}.png"), f.astype(np.uint8))
    with pytest.raises(InputError, match=r"recording folders holding them \(rec1, rec2\)"):
        run_batch([tmp_path / "rec1" / "frames", tmp_path / "rec2" / "frames"],
                  tmp_path / "out", jobs=1)
    report = run_batch([tmp_path / "rec1", tmp_path / "rec2"], tmp_path / "out", jobs=1)
    assert sorted(p.name for p in (tmp_path / "out").glob("*.irdetect.h5")) == [
        "rec1.irdetect.h5", "rec2.irdetect.h5"]
    assert all(r.status == "ok" for r in report.rows)


def test_fingerprint_sees_content_not_mtime(tmp_path):
    path = tmp_path / "s.h5"
    _simulate(path, seed=4)
    first = fingerprint(path)
    os.utime(path, ns=(1, 1))
    assert fingerprint(path)["source_digest"] == first["source_digest"]
    _simulate(path, seed=5)                 # same size, other pixels
    assert fingerprint(path)["source_size"] == first["source_size"]
    assert fingerprint(path)["source_digest"] != first["source_digest"]
    assert fingerprint(path, "/frames")["source_dataset"] == "/frames"


# --- local runs -----------------------------------------------------------------------

def test_serial_batch_recovers_the_targets(seqdir, reference):
    folder, truths = seqdir
    report, tables = reference
    assert [r.status for r in report.rows] == ["ok"] * 4
    assert sorted(tables) == sorted(truths)
    found = targets = 0
    for row in report.rows:
        name = Path(row.input).stem
        res = read_results(row.output)
        det, truth = res["detections"], truths[name]
        assert row.frames == 48 and row.detections == len(det) and row.tracks == len(res["tracks"])
        assert res.attrs["source_path"] == os.fspath((folder / f"{name}.h5").resolve())
        # the batch stores exactly what the pipeline finds on the frames in memory
        with open_sequence(folder / f"{name}.h5") as src:
            direct = detect_sequence(src[:])
        for table in TABLES:
            assert res[table].tobytes() == direct[table].tobytes(), (name, table)
        # and that is a recovery of the scene: targets found within 2 px in their window
        hit = np.zeros(truth["target"].max() + 1, bool)
        for d in det:
            at = truth[(truth["frame"] >= d["frame_start"]) & (truth["frame"] <= d["frame_end"])]
            hit[at["target"][np.hypot(at["x"] - d["x"], at["y"] - d["y"]) < 2.0]] = True
        found += int(hit.sum())
        targets += len(hit)
    assert found >= targets / 2, f"only {found} of {targets} targets detected"
    rows = _summary(Path(report.csv_path).parent)
    assert [r["status"] for r in rows] == ["ok"] * 4
    assert json.loads(Path(report.json_path).read_text())["counts"]["ok"] == 4


def test_two_processes_give_the_same_tables(seqdir, reference, tmp_path):
    report = run_batch([seqdir[0]], tmp_path, jobs=2)
    assert report.executor == "2 local processes"
    assert [r.status for r in report.rows] == ["ok"] * 4
    assert _tables(tmp_path) == reference[1]


def test_resume_skips_finished_and_refuses_stale(seqdir, tmp_path, cli):
    data = tmp_path / "data"
    shutil.copytree(seqdir[0], data)
    out = tmp_path / "out"
    code, stdout, _ = cli("process", data, "--out-dir", out, "--jobs", 1)
    assert code == 0 and "4 ok" in stdout
    first = {p.name: p.stat().st_mtime_ns for p in out.glob("*" + RESULTS_SUFFIX)}
    counts = [(r["frames"], r["detections"], r["tracks"]) for r in _summary(out)]

    code, stdout, _ = cli("process", data, "--out-dir", out, "--jobs", 1)
    assert code == 0 and "4 skipped" in stdout
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*" + RESULTS_SUFFIX)} == first
    assert [(r["frames"], r["detections"], r["tracks"]) for r in _summary(out)] == counts

    _simulate(data / "seq1.h5", seed=99)                 # a changed input is not skipped
    (tmp_path / "k5.toml").write_text("[detect]\nk = 5.0\n")
    code, stdout, _ = cli("process", data, "--out-dir", out, "--jobs", 1)
    assert code == 1
    rows = {Path(r["input"]).stem: r for r in _summary(out)}
    assert rows["seq1"]["status"] == "failed" and "different input" in rows["seq1"]["error"]
    assert "--force" in rows["seq1"]["error"] and "seq1.h5" in stdout
    assert [rows[f"seq{i}"]["status"] for i in (0, 2, 3)] == ["skipped"] * 3
    code, _, _ = cli("process", data, "--out-dir", out, "--config", tmp_path / "k5.toml")
    assert code == 1
    assert all("different configuration" in r["error"] for r in _summary(out)
               if Path(r["input"]).stem != "seq1")

    code, stdout, _ = cli("process", data, "--out-dir", out, "--jobs", 1, "--force")
    assert code == 0 and "4 ok" in stdout
    assert read_results(out / "seq1.irdetect.h5").attrs["source_digest"] == \
        fingerprint(data / "seq1.h5")["source_digest"]


def test_corrupt_input_is_reported_and_the_rest_complete(seqdir, reference, tmp_path, cli):
    data = tmp_path / "data"
    shutil.copytree(seqdir[0], data)
    (data / "broken.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 8)
    (data / "short.npy").write_bytes(b"")                  # not even a .npy header
    out = tmp_path / "out"
    code, stdout, _ = cli("process", data, "--out-dir", out, "--jobs", 2)
    assert code == 1
    rows = {Path(r["input"]).name: r for r in _summary(out)}
    assert rows["broken.h5"]["status"] == "failed" and rows["broken.h5"]["error"]
    assert rows["short.npy"]["status"] == "failed" and rows["short.npy"]["error"]
    assert [rows[f"seq{i}.h5"]["status"] for i in range(4)] == ["ok"] * 4
    assert "broken.h5" in stdout and "2 failed" in stdout
    assert not (out / "broken.irdetect.h5").exists()          # no partial output
    assert not list(out.glob(".*.tmp"))
    assert _tables(out) == reference[1]


def test_single_input_form_is_unchanged(seqdir, cli, tmp_path):
    seq = seqdir[0] / "seq0.h5"
    code, _, _ = cli("process", seq, "-o", "one.h5")
    assert code == 0 and (tmp_path / "one.h5").exists()
    assert not (tmp_path / f"{SUMMARY_NAME}.csv").exists()
    code, _, err = cli("process", seq, "-o", "one.h5")
    assert code == 2 and "--force" in err
    code, _, _ = cli("process", seq)
    assert code == 0 and (tmp_path / "seq0.irdetect.h5").exists()


@pytest.mark.parametrize("argv, message", [
    (["A", "B"], "2 inputs: give --out-dir DIR"),
    (["A", "B", "-o", "x.h5"], "-o names the output of a single input"),
    (["DIR"], "a folder of sequences or a pattern: give --out-dir"),
    (["A", "--out-dir", "o", "-o", "x.h5"], "not both"),
    (["A", "--out-dir", "o", "--jobs", "0"], "--jobs must be >= 1"),
])
def test_cli_batch_argument_errors(seqdir, cli, argv, message):
    subst = {"A": seqdir[0] / "seq0.h5", "B": seqdir[0] / "seq1.h5", "DIR": seqdir[0]}
    code, _, err = cli("process", *(subst.get(a, a) for a in argv))
    assert code == 2 and message in err and "Traceback" not in err


def test_map_tasks_keeps_order_and_names_the_failing_item():
    assert map_tasks(abs, [-3, 1, -2, 5, -8], jobs=2) == [3, 1, 2, 5, 8]
    assert map_tasks(abs, [-1], jobs=1) == [1]
    with pytest.raises(ValueError, match="invalid literal") as info:
        map_tasks(int, ["1", "x", "3"], jobs=2)
    assert "task 1 of 3: 'x'" in info.value.__notes__[0]
    outcomes = sorted(imap_tasks(int, ["1", "x"], jobs=1), key=lambda o: o[0])
    assert outcomes[0] == (0, 1, None) and isinstance(outcomes[1][2], ValueError)
    with pytest.raises(ValueError, match="jobs must be an integer >= 1, got 0"):
        map_tasks(abs, [1], jobs=0)


def test_dead_local_process_is_reported_not_raised():
    from concurrent.futures.process import BrokenProcessPool

    outcomes = {i: (v, e) for i, v, e in imap_tasks(_exit_or_square, [2, -1, 3], jobs=2)}
    assert sorted(outcomes) == [0, 1, 2]
    assert isinstance(outcomes[1][1], BrokenProcessPool)
    for i, x in ((0, 2), (2, 3)):       # done before the pool broke, or lost with it
        value, error = outcomes[i]
        assert value == x * x if error is None else isinstance(error, BrokenProcessPool)


def test_missing_distributed_gives_an_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)     # import fails as if absent
    with pytest.raises(InputError, match=r"pip install 'irdetect\[distributed\]'"):
        map_tasks(abs, [1, 2], scheduler="tcp://127.0.0.1:1")


# --- Dask -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def cluster():
    """A 2-worker LocalCluster (processes) on loopback; a task may kill 1 worker and retry."""
    import dask
    import distributed
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])    # workers lack tests/
    # worker-saturation 1.0: a worker holds only the task it runs, so a task that kills its
    # worker takes no queued bystander down with it (Dask would count those as suspects too)
    with dask.config.set({"distributed.scheduler.allowed-failures": 1,
                          "distributed.scheduler.worker-saturation": 1.0}):
        lc = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      host="127.0.0.1", dashboard_address=None)
    client = distributed.Client(lc, set_as_default=False)
    try:
        yield lc, client
    finally:
        client.close()
        lc.close()
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def test_dask_cluster_gives_the_same_tables(seqdir, reference, cluster, tmp_path, cli,
                                            monkeypatch):
    lc, client = cluster
    report = run_batch([seqdir[0]], tmp_path / "client", scheduler=client)
    assert [r.status for r in report.rows] == ["ok"] * 4
    assert _tables(tmp_path / "client") == reference[1]
    # the workers were tuned: one OpenCV thread per Dask worker thread
    assert set(client.run(cv2.getNumThreads).values()) == {1}
    assert set(client.run(_worker_tuned).values()) == {True}
    # a scheduler file (dask scheduler --scheduler-file) names the cluster as well
    sched = tmp_path / "sched.json"
    sched.write_text(json.dumps({"address": lc.scheduler_address}))
    assert map_tasks(abs, [-2, 3, -5], scheduler=str(sched)) == [2, 3, 5]
    # the address from the environment, through the CLI
    monkeypatch.setenv("IRDETECT_SCHEDULER", lc.scheduler_address)
    code, stdout, _ = cli("process", str(seqdir[0] / "seq*.h5"), "--out-dir", "cli")
    assert code == 0 and f"dask {lc.scheduler_address}" in stdout
    assert _tables(tmp_path / "cli") == reference[1]


def test_unreachable_scheduler_is_an_input_error(seqdir, tmp_path, cli, monkeypatch):
    monkeypatch.setattr("irdetect.batch.CONNECT_TIMEOUT", 1.0)
    code, _, err = cli("process", seqdir[0], "--out-dir", "o", "--scheduler",
                       "tcp://127.0.0.1:9")
    assert code == 2 and "cannot reach the Dask scheduler" in err


def _pids(lc) -> dict[str, int]:
    return {n.worker_address: n.process.process.pid for n in lc.workers.values()
            if n.process is not None and n.process.process is not None}


def test_killed_worker_mid_run_still_completes(cluster, tmp_path):
    lc, client = cluster
    data = tmp_path / "data"
    data.mkdir()
    for i in range(6):
        _simulate(data / f"s{i}.h5", seed=40 + i, height=128, width=128, n_frames=60)
    expected_dir = tmp_path / "serial"
    run_batch([data], expected_dir, jobs=1)
    killed: list[int] = []

    def killer():
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not killed:
            busy = [w for w, keys in client.processing().items()
                    if any("_process_one" in str(k) for k in keys)]
            pids = _pids(lc)
            if busy and busy[0] in pids:
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(pids[busy[0]])
            time.sleep(0.002)

    thread = threading.Thread(target=killer)
    thread.start()
    try:
        report = run_batch([data], tmp_path / "dask", scheduler=client)
    finally:
        thread.join()
    assert killed, "no worker was busy long enough to be killed"
    assert [r.status for r in report.rows] == ["ok"] * 6     # the lost task was retried
    assert _tables(tmp_path / "dask") == _tables(expected_dir)
    assert not list((tmp_path / "dask").glob(".*.tmp"))     # the dead worker's temp file
    client.wait_for_workers(2, timeout=60)


def _worker_tuned() -> bool:
    import irdetect.batch
    return irdetect.batch._WORKER_TUNED


def _exit_or_square(x):
    if x < 0:
        os._exit(3)                     # the worker process dies, every time
    return x * x


def test_task_that_keeps_killing_workers_is_reported_lost(cluster):
    lc, client = cluster
    client.wait_for_workers(2, timeout=60)
    outcomes = {i: (v, e) for i, v, e in imap_tasks(_exit_or_square, [2, -1, 3],
                                                    scheduler=client)}
    assert outcomes[0] == (4, None) and outcomes[2] == (9, None)
    assert type(outcomes[1][1]).__name__ == "KilledWorker"
    client.wait_for_workers(2, timeout=60)
