#!/usr/bin/env python
"""Front-end throughput from HDF5; writes docs/results/throughput.md.

For each frame size (256x256, 320x240, 640x512; uint16, simulated into a temporary folder,
``--frames`` frames each, default 1,200) it measures, in the same run:

1. the raw floor: reading the frames with h5py (chunk-aligned ``read_direct`` into one
   buffer) and taking the max of every 12-frame window;
2. ``irdetect process`` end to end as a child process (the CLI a user runs), for the
   default configuration and ``--profile fast``, each with the CLI's default 2 threads
   and with ``--threads 1``: wall time with and without interpreter start-up and
   imports, CPU time, peak RSS;
3. per-stage seconds (``process_file(timings=...)`` in a child process), with 1 and 2
   worker threads, for the default configuration, for ``suppress.method =
   "temporal"`` (the static-camera path) and for the ``fast`` profile;
4. ``irdetect track`` (the frame-by-frame tracker, defaults) end to end as a child
   process on the same sequences: wall, in-run seconds, CPU time, peak RSS;
5. trackpy ``locate`` frames/s on the same frames (the peer a user would reach for;
   skipped with a note when trackpy is not installed: it is not a dependency).

Those inputs have a flat background, on which ``auto`` takes the still-camera background. Real
footage takes the registered one with its fixed-pattern estimate, so "footage" times
``irdetect process`` (2 threads, whole command) and its stages (1 worker) on the clutter
preset at 640x512 (``--footage-frames``, clouds, a horizon and hot pixels) and on every
folder of ../shared/data/real (PNG frames; skipped when absent). ``--footage-only`` measures
only these and saves them (``--json``); ``--before-footage JSON`` adds such a run of another
checkout beside this one's.

Then streaming memory: peak RSS of ``irdetect process`` (temporal suppressor, and the fast
profile) and of ``irdetect track`` on 20,000 frames of 256x256 (``--long``) against the
1,200-frame run; and the compiled kernels' cold start (``irdetect process`` on 48 frames
with an empty numba cache: the kernels compile) and warm start (the same again: they load
from the cache).

``--before JSON`` adds the figures of an earlier run (the raw measurements another
checkout of this script saved with ``--json``) beside this run's: end to end and per
stage, before and after.

The machine has 2 cores; other sessions may be loading them, so the table records the
load average before and after and reports CPU-time frames/s next to wall-clock frames/s.

Usage::

    .venv/bin/python scripts/bench_throughput.py                 # the documented run
    .venv/bin/python scripts/bench_throughput.py --frames 240 --long 2400 --out /tmp/t.md
    .venv/bin/python scripts/bench_throughput.py --before /tmp/before.json
    OTHER/.venv/bin/python scripts/bench_throughput.py --footage-only \
        --json /tmp/footage_before.json     # the Python of an environment with another
                                            # checkout installed: that checkout's code
    .venv/bin/python scripts/bench_throughput.py --before-footage /tmp/footage_before.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
SIZES = ((256, 256), (240, 320), (512, 640))    # (height, width)
STAGES = ("read", "suppress", "combine", "frame", "detect", "fuse", "correlate", "operate",
          "write", "initiate")
TEMPORAL = '[suppress]\nmethod = "temporal"\n'
#: frames/s goals of issues 19 and 27 (2 cores, end to end from HDF5, within 5x of the
#: floor): (size, CLI run) -> fps; issue 9 had asked 3,000 and 500 of both profiles
GOAL_FPS = {("256x256", "default"): 3000, ("256x256", "--profile fast"): 6000,
            ("640x512", "default"): 600, ("640x512", "--profile fast"): 600}
#: per-stage runs: (label, profile, temporal config?, workers)
RUNS = (("default (auto)", "default", False, 1), ("default (auto)", "default", False, 2),
        ("temporal", "default", True, 1), ("temporal", "default", True, 2),
        ("fast", "fast", False, 1), ("fast", "fast", False, 2),
        ("fast, temporal", "fast", True, 1))
#: ``irdetect process`` runs per size: (label, options); the CLI's default is --threads 2
CLI_RUNS = (("default", []), ("default --threads 1", ["--threads", "1"]),
            ("--profile fast", ["--profile", "fast"]),
            ("--profile fast --threads 1", ["--profile", "fast", "--threads", "1"]))


# --- inputs -----------------------------------------------------------------------------

def generate(path: Path, height: int, width: int, n_frames: int, seed: int = 0,
             scenario: str = "wan2008") -> float:
    """Simulate a uint16 sequence of 5 targets (SNR 4, 1 px/frame) in streamed blocks.

    New targets every 240 frames (a target at 1 px/frame leaves a small frame long before
    1,200 frames); nothing is held but one block. ``scenario``: the preset (the clutter
    preset adds its clouds, horizon and hot pixels). Returns the seconds taken.
    """
    from irdetect.io import write_sequence
    from irdetect.simulate.sequence import load_scenario, simulate_blocks

    segment = 240
    t0 = time.perf_counter()

    def blocks():
        for k, start in enumerate(range(0, n_frames, segment)):
            s = load_scenario(scenario, height=height, width=width,
                              n_frames=min(segment, n_frames - start), dtype="uint16",
                              background=1000.0, noise_sigma=20.0, snr=4.0, directions=[])
            frames, _ = simulate_blocks(s, rng=seed * 100_000 + k)
            yield from frames

    write_sequence(path, blocks(), attrs={"frame_rate": 100.0}, force=True)
    return time.perf_counter() - t0


# --- measurements -----------------------------------------------------------------------

def raw_floor(path: Path, length: int = 12) -> dict:
    """Read every frame with h5py in chunk-aligned blocks and take each window's max."""
    import h5py

    t0, c0 = time.perf_counter(), time.process_time()
    with h5py.File(path, "r") as f:
        dset = f["frames"]
        n, h, w = dset.shape
        block = max(length, (dset.chunks or (length,))[0])
        block -= block % length
        buf = np.empty((block, h, w), dset.dtype)
        out = np.empty((h, w), dset.dtype)
        for start in range(0, n - length + 1, block):
            stop = min(n, start + block)
            dset.read_direct(buf, np.s_[start:stop], np.s_[0:stop - start])
            for s in range(0, stop - start - length + 1, length):
                np.max(buf[s:s + length], axis=0, out=out)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"frames": n, "wall": wall, "cpu": cpu}


#: appended to every child: print its peak RSS. VmHWM of /proc/self/status belongs to
#: the process image after exec; getrusage's ru_maxrss would include the (large) RSS of
#: this benchmark process at fork time, which Linux carries over into the child.
PEAK = """
def _peak():
    import sys
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            print("PEAK_RSS_KB", int(line.split()[1]), file=sys.stderr)
"""

#: ``irdetect process`` exactly as ``python -m irdetect`` runs it, then the peak RSS; the
#: run is timed after the imports the CLI does at start-up (``build_parser``) and those
#: its ``process`` command does first (the pipeline's: numpy, scipy, OpenCV, h5py)
CLI = PEAK + """
import sys, time
from irdetect.cli import build_parser, main
import irdetect.initiate, irdetect.pipeline
build_parser()
t0 = time.perf_counter()
code = main(sys.argv[1:])
print("RUN_SECONDS", time.perf_counter() - t0, file=sys.stderr)
_peak()
sys.exit(code)
"""


def _child(cmd: list[str]) -> tuple[str, str, dict]:
    """Run a child process; (stdout, stderr, {wall, cpu seconds, peak RSS in MB}).

    ``os.wait4`` gives the CPU time of that child alone; the peak RSS comes from the
    child itself (``PEAK``). Output goes to files, so a chatty child cannot block.
    """
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = code = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if code != 0:
        raise RuntimeError(f"{' '.join(cmd[:4])} failed ({code}): {stderr.strip()[-400:]}")
    m = re.search(r"^PEAK_RSS_KB (\d+)$", stderr, re.M)
    return stdout, stderr, {"wall": wall, "cpu": usage.ru_utime + usage.ru_stime,
                            "rss_mb": int(m.group(1)) / 1024.0 if m else float("nan")}


def run_cli(path: Path, out: Path, config: Path | None = None,
            options: list[str] | None = None, command: str = "process") -> dict:
    """``irdetect process`` (or ``command``) as a user runs it: wall (with start-up),
    in-run seconds, RSS."""
    cmd = [sys.executable, "-c", CLI, command, str(path), "-o", str(out), "--force"]
    if config is not None:
        cmd += ["--config", str(config)]
    _, stderr, usage = _child(cmd + list(options or []))
    m = re.search(r"^RUN_SECONDS ([0-9.e+-]+)$", stderr, re.M)
    return {"run": float(m.group(1)) if m else float("nan"), **usage}


CHILD = PEAK + """
import json, sys, time
import irdetect.initiate    # imported before the clock starts, as the CLI does at start-up
from irdetect.profiles import load_profile
from irdetect.pipeline import process_file
path, out, config, workers, profile = (sys.argv[1], sys.argv[2], sys.argv[3] or None,
                                       int(sys.argv[4]), sys.argv[5])
timings = {}
t0, c0 = time.perf_counter(), time.process_time()
r = process_file(path, out, load_profile(profile, config), force=True, workers=workers,
                 timings=timings)
print(json.dumps({"wall": time.perf_counter() - t0, "proc_cpu": time.process_time() - c0,
                  "timings": timings, "detections": r["detections"]}))
_peak()
"""


def run_stages(path: Path, out: Path, config: Path | None, workers: int,
               profile: str = "default") -> dict:
    """Per-stage seconds of ``process_file`` in a child process."""
    cmd = [sys.executable, "-c", CHILD, str(path), str(out), str(config or ""), str(workers),
           profile]
    stdout, _, usage = _child(cmd)
    usage.pop("wall")           # the child's own wall time (without start-up) is kept
    return {**json.loads(stdout.strip().splitlines()[-1]), **usage}


def trackpy_rate(path: Path, n_frames: int) -> dict | None:
    """trackpy.locate frames/s on the first ``n_frames`` frames (None: not installed)."""
    try:
        import trackpy
    except ImportError:
        return None
    import logging

    import h5py

    trackpy.quiet()
    logging.getLogger("trackpy").setLevel(logging.ERROR)
    with h5py.File(path, "r") as f:
        frames = f["frames"][:n_frames]
    trackpy.locate(frames[0], 5)       # warm-up (numba / imports)
    t0 = time.perf_counter()
    found = 0
    for frame in frames:
        found += len(trackpy.locate(frame, 5))
    wall = time.perf_counter() - t0
    return {"frames": len(frames), "wall": wall, "version": trackpy.__version__,
            "features": found / len(frames)}


# --- report -----------------------------------------------------------------------------

def _goal_fps(name: str, label: str = "default") -> int | None:
    """The frames/s goal of a frame size named "WxH" and CLI run, None for the others."""
    return GOAL_FPS.get((name, label))


def fps(n: int, seconds: float) -> str:
    return f"{n / seconds:,.0f}" if seconds > 0 and np.isfinite(seconds) else "-"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1200, help="frames per size (default 1200)")
    ap.add_argument("--long", type=int, default=20000,
                    help="frames of the 256x256 streaming-memory run (0 = skip)")
    ap.add_argument("--trackpy-frames", type=int, default=48)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "throughput.md"))
    ap.add_argument("--tmp", help="folder for the simulated sequences (default: a temp dir)")
    ap.add_argument("--json", help="also save the raw measurements here (default: the output "
                    "path with .json)")
    ap.add_argument("--from-json", help="write the table from saved measurements, measure nothing")
    ap.add_argument("--before", help="measurements of an earlier run (its --json) to compare "
                    "with, end to end and per stage")
    ap.add_argument("--footage-frames", type=int, default=480,
                    help="frames of the clutter preset at 640x512 (default 480)")
    ap.add_argument("--footage-only", action="store_true",
                    help="measure only the footage section and save it (--json); no report")
    ap.add_argument("--before-footage", help="a --footage-only run of another checkout, "
                    "shown beside this run's footage")
    ap.add_argument("--label", default="", help="with --footage-only: what code was measured "
                    "(shown with it as the before)")
    args = ap.parse_args(argv)
    if args.footage_only:
        with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
            data = {"footage": footage(Path(tmp), args.footage_frames),
                    "when": time.strftime("%Y-%m-%d %H:%M"), "load": list(os.getloadavg()),
                    "label": args.label}
        Path(args.json or "footage.json").write_text(json.dumps(data))
        return 0
    if args.from_json:
        data = json.loads(Path(args.from_json).read_text())
    else:
        data = measure(args)
        Path(args.json or Path(args.out).with_suffix(".json")).write_text(json.dumps(data))
    if args.before:
        data["before"] = json.loads(Path(args.before).read_text())
        data["before"]["path"] = args.before
    if args.before_footage:
        data["before_footage"] = json.loads(Path(args.before_footage).read_text())
        data["before_footage"]["path"] = args.before_footage
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    figure = stage_figure(Path(args.out).with_name("throughput-stages.png"), data)
    text = report(data, figure=figure.name if figure else None)
    Path(args.out).write_text(text)
    print(text)
    return 0


def measure(args) -> dict:
    """Run every measurement; a JSON-able dict for ``report``."""
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        tmp = Path(tmp)
        temporal = tmp / "temporal.toml"
        temporal.write_text(TEMPORAL)
        rows, stage_rows, peer_rows, track_rows = [], [], [], []
        for h, w in SIZES:
            name = f"{w}x{h}"
            seq = tmp / f"seq_{name}.h5"
            gen = generate(seq, h, w, args.frames)
            print(f"{name}: simulated {args.frames} frames in {gen:.1f} s", flush=True)
            floor = raw_floor(seq)
            cli = {}
            for label, options in CLI_RUNS:
                cli[label] = run_cli(seq, tmp / "out.h5", options=options)
                print(f"{name}: floor {fps(floor['frames'], floor['wall'])} fps, irdetect "
                      f"process {label}: {fps(args.frames, cli[label]['wall'])} fps (in-run "
                      f"{fps(args.frames, cli[label]['run'])}, per CPU-s "
                      f"{fps(args.frames, cli[label]['cpu'])})", flush=True)
            for label, profile, is_temporal, workers in RUNS:
                st = run_stages(seq, tmp / "out.h5", temporal if is_temporal else None,
                                workers, profile)
                stage_rows.append((name, label, workers, st))
                print(f"{name} {label} workers={workers}: {fps(args.frames, st['wall'])} "
                      f"fps", flush=True)
            rows.append((name, floor, cli))
            track_rows.append((name, run_cli(seq, tmp / "tracks.h5", command="track")))
            print(f"{name}: irdetect track {fps(args.frames, track_rows[-1][1]['wall'])} "
                  f"fps, {track_rows[-1][1]['rss_mb']:.0f} MB", flush=True)
            peer_rows.append((name, trackpy_rate(seq, args.trackpy_frames), cli))
            seq.unlink()
        long_rows, long_track = [], []
        if args.long:
            for n in sorted({args.frames, args.long}):
                seq = tmp / f"long_{n}.h5"
                gen = generate(seq, 256, 256, n, seed=1)
                r = run_cli(seq, tmp / "out.h5", temporal)
                r_fast = run_cli(seq, tmp / "out.h5", options=["--profile", "fast"])
                r_auto = run_cli(seq, tmp / "out.h5") if n == args.frames else None
                long_rows.append((n, r, r_auto, r_fast))
                long_track.append((n, run_cli(seq, tmp / "tracks.h5", command="track")))
                print(f"long {n}: simulated in {gen:.0f} s, rss {r['rss_mb']:.0f} MB "
                      f"(fast {r_fast['rss_mb']:.0f} MB, track "
                      f"{long_track[-1][1]['rss_mb']:.0f} MB), {fps(n, r['wall'])} fps",
                      flush=True)
                seq.unlink()
        starts = start_times(tmp)
        footage_rows = footage(tmp, args.footage_frames)
    load1 = os.getloadavg()
    return {"frames": args.frames, "load": [load0[0], load1[0]], "cores": os.cpu_count(),
            "when": time.strftime("%Y-%m-%d %H:%M"),
            "machine": platform.processor() or platform.machine(),
            "versions": [platform.python_version(), np.__version__, _cv2_version()],
            "rows": rows, "stage_rows": stage_rows, "peer_rows": peer_rows,
            "long_rows": long_rows, "starts": starts, "footage": footage_rows,
            "track_rows": track_rows, "long_track": long_track}


def footage(tmp: Path, n_frames: int) -> list:
    """``irdetect process`` (default, 2 threads) and its stages (1 worker) on the clutter
    preset at 640x512 and on every folder of ../shared/data/real: rows of (name, frames,
    "WxH", CLI measurement, stage measurement)."""
    from irdetect.io import open_sequence

    seq = tmp / "footage_clutter.h5"
    generate(seq, 512, 640, n_frames, seed=3, scenario="clutter")
    inputs = [("clutter preset", seq)]
    if REAL.is_dir():
        inputs += [(d.name, d / "frames") for d in sorted(REAL.iterdir())
                   if (d / "frames").is_dir()]
    run_cli(inputs[0][1], tmp / "out.h5")          # kernels compiled or loaded, files cached
    rows = []
    for name, path in inputs:
        shape = open_sequence(path).shape
        cli = run_cli(path, tmp / "out.h5")
        st = run_stages(path, tmp / "out.h5", None, 1)
        rows.append((name, int(shape[0]), f"{shape[2]}x{shape[1]}", cli, st))
        print(f"footage {name}: {fps(shape[0], cli['run'])} fps in-run, "
              f"{cli['rss_mb']:.0f} MB", flush=True)
    seq.unlink()
    return rows


def start_times(tmp: Path) -> dict:
    """Cold and warm start of ``irdetect process`` on 48 frames of 256x256: wall seconds
    of the whole command with an empty numba cache (the kernels compile) and again with
    it filled (they load), and each run's start-up (wall minus the run's own seconds)."""
    seq = tmp / "start.h5"
    generate(seq, 256, 256, 48, seed=2)
    out = {}
    with tempfile.TemporaryDirectory(dir=tmp) as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for label in ("cold", "warm"):
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-c", CLI, "process", str(seq), "-o",
                                str(tmp / "start_out.h5"), "--force"], env=env,
                               capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if r.returncode != 0:
                raise RuntimeError(f"start-up run failed: {r.stderr.strip()[-400:]}")
            run = float(re.search(r"^RUN_SECONDS ([0-9.e+-]+)$", r.stderr, re.M).group(1))
            out[label] = {"wall": wall, "run": run,
                          "said": "compiling kernels, once" in r.stderr}
            print(f"{label} start: {wall:.1f} s whole command, {run:.1f} s in the run",
                  flush=True)
    return out


def stage_figure(path, data: dict):
    """PNG of frames/s per stage (frames / seconds in the stage, 1 worker) for every frame
    size, the default configuration and the fast profile; None without matplotlib."""
    from _figures import save_bars

    n = data["frames"]
    panels = []
    for label in ("default (auto)", "fast"):
        groups = [{"label": name, "values": [n / max(st["timings"].get(s, 0.0), 1e-9)
                                             for s in STAGES]}
                  for name, lab, workers, st in data["stage_rows"]
                  if lab == label and workers == 1]
        if groups:
            panels.append({"categories": list(STAGES), "groups": groups, "yscale": "log",
                           "ylabel": "frames/s of the stage alone (1 worker)",
                           "title": f"{label}: {n:,} frames per size"})
    return save_bars(path, panels, width=6.5) if panels else None


def report(data: dict, figure: str | None = None) -> str:
    """The markdown of docs/results/throughput.md from ``measure``'s results; ``figure``
    names the PNG of frames/s per stage, linked under the per-stage table."""
    n = data["frames"]
    load0, load1 = data["load"]
    cores = data["cores"]
    rows, stage_rows = data["rows"], data["stage_rows"]
    peer_rows, long_rows = data["peer_rows"], data["long_rows"]
    lines = [
        "# Throughput of the front end (issues 9, 19 and 27)",
        "",
        f"Produced by `scripts/bench_throughput.py` on {data['when']}: "
        f"{cores} cores ({data['machine']}), Python {data['versions'][0]}, "
        f"numpy {data['versions'][1]}, OpenCV {data['versions'][2]}.",
        f"Load average before / after: {load0:.1f} / {load1:.1f} on {cores} "
        "cores (the one-minute figure after includes this benchmark's own runs)"
        + (" -- other jobs were loading the machine when this started, so wall-clock "
           "rates (and what a second thread gives) are below what an idle machine "
           "gives; the CPU-time rates (frames per CPU-second of the process) are the "
           "steadier figure." if load0 > 0.5 * (cores or 1) else "."),
        "",
        f"Inputs: simulated uint16 HDF5 sequences of {n} frames (64-frame chunks, "
        "uncompressed, in the page cache), 5 targets at SNR 4 (noise sigma 20 grey levels "
        "on 1000). `default`: the default configuration (matched-filter verification); "
        "`fast`: `--profile fast` (no verification; quality in docs/results/profiles.md); "
        "`temporal`: the default with `suppress.method = \"temporal\"` (the still-camera "
        "suppressor without `auto`'s motion check); `fast, temporal`: the fast profile "
        "with it. `irdetect process` runs 2 threads "
        "unless `--threads 1` (`--threads`: the results do not depend on it).",
        "",
        "## End to end: `irdetect process` from HDF5",
        "",
        "| frames | run | raw floor fps (read + 12-frame max) | fps, wall incl. start-up | "
        "fps in the run (excl. start-up) | ratio to floor (in-run) | fps per CPU-second "
        "(whole process) | peak RSS MB |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, floor, cli in rows:
        ffps = fps(floor["frames"], floor["wall"])
        for label, r in cli.items():
            ratio = (n / floor["wall"]) / (n / r["run"]) if r["run"] > 0 else float("nan")
            lines.append(f"| {name} | `{label}` | {ffps} | {fps(n, r['wall'])} | "
                         f"{fps(n, r['run'])} | {ratio:.1f}x | {fps(n, r['cpu'])} | "
                         f"{r['rss_mb']:.0f} |")
    lines += [
        "",
        "Start-up (interpreter, imports of numpy / scipy / h5py / OpenCV and the CLI's "
        "commands) is the difference between the wall and in-run columns. The fps per "
        "CPU-second of a 2-thread run counts both threads' CPU time.",
        "",
    ]
    if data.get("track_rows"):
        lines += [
            "## End to end: `irdetect track` from HDF5",
            "",
            "The frame-by-frame tracker with its defaults (the per-frame detector's regions, "
            "FCM + adaptive PMHT; `track` has no `--threads`) on the same sequences. The in-run "
            "seconds include importing `irdetect.track`.",
            "",
            "| frames | fps, wall incl. start-up | fps in the run (excl. start-up) | fps per "
            "CPU-second (whole process) | peak RSS MB |",
            "|---|---|---|---|---|",
        ]
        lines += [f"| {name} | {fps(n, r['wall'])} | {fps(n, r['run'])} | "
                  f"{fps(n, r['cpu'])} | {r['rss_mb']:.0f} |" for name, r in data["track_rows"]]
        lines.append("")
    lines += [
        "## Per stage (seconds in the stage, summed over threads; `process_file` in a child "
        "process)",
        "",
        "`combine` includes the PSF-matched, standardised residual frames that the "
        "verification in `correlate` integrates along each chain; `correlate` includes that "
        "verification (not in `fast`); `operate`: each window's operating point and its "
        "detections' SNR along their tracks (timed since 2026-12-06; before, this work "
        "was in no stage: the earlier runs' totals leave it out). With 2 workers the correlation of each window triple "
        "runs beside the next windows' front end; a stage's seconds then include waiting "
        "for the other thread (GIL, memory).",
        "",
        "| frames | config | workers | " + " | ".join(STAGES) + " | wall s | fps | CPU s | "
        "fps per CPU-s |",
        "|---|---|---|" + "---|" * len(STAGES) + "---|---|---|---|",
    ]
    for name, label, workers, st in stage_rows:
        t = st["timings"]
        lines.append(f"| {name} | {label} | {workers} | "
                     + " | ".join(f"{t.get(s, 0.0):.2f}" for s in STAGES)
                     + f" | {st['wall']:.2f} | {fps(n, st['wall'])} | {st['cpu']:.2f} | "
                     f"{fps(n, st['proc_cpu'])} |")
    if figure:
        lines += ["", f"![frames/s per stage, 1 worker]({figure})"]
    lines += [
        "",
        "## Against trackpy `locate`",
        "",
        "| frames | trackpy locate fps (diameter 5, one frame at a time) | irdetect process "
        "fps in-run (default / fast) | speed-up (default / fast) |",
        "|---|---|---|---|",
    ]
    for name, tp, cli in peer_rows:
        d, f = cli["default"], cli["--profile fast"]
        if tp is None:
            lines.append(f"| {name} | trackpy not installed (`pip install trackpy` in the "
                         "benchmark environment; not a dependency) | | |")
            continue
        tfps = tp["frames"] / tp["wall"]
        lines.append(f"| {name} | {tfps:,.1f} ({tp['frames']} frames, trackpy {tp['version']}) "
                     f"| {fps(n, d['run'])} / {fps(n, f['run'])} | "
                     f"{(n / d['run']) / tfps:.1f}x / {(n / f['run']) / tfps:.1f}x |")
    if long_rows:
        lines += [
            "",
            "## Streaming memory: peak RSS against sequence length (256x256)",
            "",
            "| frames | `irdetect process` (temporal) peak RSS MB | fps in the run | default "
            "peak RSS MB | `--profile fast` peak RSS MB | fast fps in the run | "
            "`irdetect track` peak RSS MB | track fps in the run |",
            "|---|---|---|---|---|---|---|---|",
        ]
        tracked = dict(data.get("long_track", []))
        for frames, r, r_auto, r_fast in long_rows:
            auto = "-" if r_auto is None else f"{r_auto['rss_mb']:.0f}"
            trk = tracked.get(frames)
            trk = ("- | -" if trk is None else
                   f"{trk['rss_mb']:.0f} | {fps(frames, trk['run'])}")
            lines.append(f"| {frames:,} | {r['rss_mb']:.0f} | {fps(frames, r['run'])} | "
                         f"{auto} | {r_fast['rss_mb']:.0f} | {fps(frames, r_fast['run'])} | "
                         f"{trk} |")
    lines += ["", "## Where the time goes (1 worker)", ""]
    for name, label, workers, st in stage_rows:
        if label in ("default (auto)", "fast") and workers == 1:
            t = st["timings"]
            total = sum(t.values()) or 1.0
            top = sorted(t.items(), key=lambda kv: -kv[1])[:3]
            lines.append(f"- {name} {label}: " + ", ".join(f"{k} {100 * v / total:.0f} %"
                                                         for k, v in top)
                         + f" of the {total:.1f} s in stages ({1e3 * total / n:.2f} ms per "
                         "frame).")
    lines += ["", "## What the goal leaves per frame", ""]
    for name, floor, cli in rows:
        goal = _goal_fps(name)
        one = {label: st["timings"] for nm, label, workers, st in stage_rows
               if nm == name and workers == 1}
        if goal is None or "default (auto)" not in one or "fast" not in one:
            continue
        budget = min(1.0 / goal, 5.0 * floor["wall"] / n)
        per = {label: {k: 1e3 * v / n for k, v in t.items()} for label, t in one.items()}
        lines.append(
            f"- {name}: {goal:,} fps within 5x of this run's floor leaves "
            f"{1e3 * budget:.2f} ms per frame ({1e3 * cores * budget:.2f} ms of CPU on "
            f"{cores} cores). "
            f"On one worker the stages take {sum(per['default (auto)'].values()):.2f} ms "
            f"(default) and {sum(per['fast'].values()):.2f} ms (fast) per frame; "
            f"suppression alone {per['fast']['suppress']:.2f} ms, the combination "
            f"{per['fast']['combine']:.2f} ms (fast), the correlation with its "
            f"verification {per['default (auto)']['correlate']:.2f} ms (default).")
    lines += ["", "## Goals (issues 19 and 27, 2 cores)", ""]
    for name, floor, cli in rows:
        for label in ("default", "--profile fast"):
            goal = _goal_fps(name, label)
            if goal is None:
                continue
            r = cli[label]
            got = n / r["run"]
            ratio = (n / floor["wall"]) / got
            lines.append(f"- {name} `{label}`: goal >= {goal:,} fps end to end "
                         f"within 5x of the floor; measured {got:,.0f} fps in-run "
                         f"({fps(n, r['wall'])} with start-up, {fps(n, r['cpu'])} per "
                         f"CPU-second), {ratio:.1f}x the floor -> "
                         f"{'reached' if got >= goal and ratio <= 5 else 'not reached'}.")
    speedups = [(name, (n / cli[label]["run"]) / (tp["frames"] / tp["wall"]))
                for name, tp, cli in peer_rows if tp is not None
                for label in ("default", "--profile fast")]
    if speedups:
        worst = min(speedups, key=lambda kv: kv[1])
        lines.append(f"- >= 20x trackpy `locate` on the same frames: lowest measured "
                     f"{worst[1]:.1f}x ({worst[0]}) -> "
                     f"{'reached' if worst[1] >= 20 else 'not reached'}.")
    peaks = [(f"{name} `{label}`", r["rss_mb"]) for name, _, cli in rows
             for label, r in cli.items()]
    peaks += [(f"{frames:,} frames of 256x256", r["rss_mb"]) for frames, r, _, _ in long_rows]
    if peaks:
        top = max(peaks, key=lambda kv: kv[1])
        grows = ""
        if len(long_rows) > 1:
            (n0, a, _, fa), (n1, b, _, fb) = long_rows[0], long_rows[-1]
            grows = (f"; from {n0:,} to {n1:,} frames it went {a['rss_mb']:.0f} -> "
                     f"{b['rss_mb']:.0f} MB (temporal) and {fa['rss_mb']:.0f} -> "
                     f"{fb['rss_mb']:.0f} MB (`fast`): streaming memory above")
        lines.append(f"- peak memory under 400 MB for any length: highest peak RSS "
                     f"{top[1]:.0f} MB ({top[0]}) -> "
                     f"{'reached' if top[1] < 400 else 'not reached'}{grows}.")
    starts = data.get("starts")
    if starts:
        cold, warm = starts["cold"], starts["warm"]
        lines += [
            "",
            "## Start-up with the compiled kernels (issue 27)",
            "",
            "`irdetect process` on 48 frames of 256x256 with an empty numba cache "
            "(`NUMBA_CACHE_DIR`: the first run after an install compiles the kernels) and "
            "again with the cache filled:",
            "",
            "| start | whole command s | in the run s (compiling or loading the kernels, "
            "then 48 frames) | said \"compiling kernels, once\" |",
            "|---|---|---|---|",
            f"| cold | {cold['wall']:.1f} | {cold['run']:.1f} | {'yes' if cold['said'] else 'no'} |",
            f"| warm | {warm['wall']:.1f} | {warm['run']:.1f} | {'yes' if warm['said'] else 'no'} |",
            "",
            f"- cold start (compilation) under 30 s: {cold['wall'] - warm['wall']:.1f} s more "
            f"than a warm run -> {'reached' if cold['wall'] - warm['wall'] < 30 else 'not reached'}.",
            f"- warm start (to the first frame) under 1 s: the whole warm command took "
            f"{warm['wall']:.1f} s for 48 frames, of which {warm['wall'] - warm['run']:.1f} s "
            "before the run (interpreter and imports) -> "
            f"{'reached' if warm['wall'] - warm['run'] < 1 else 'not reached'}.",
        ]
    if data.get("footage"):
        lines += footage_report(data)
    if data.get("before"):
        lines += before_after(data)
    lines += [
        "",
        "## How the front end streams (what these numbers rest on)",
        "",
        "- Frames are read in the stored dtype into one reused buffer of `history + length + "
        "one read-ahead block` frames with `read_direct` (the block: a compressed HDF5 "
        "chunk, or at most 8 MB of plain chunks), ahead in chunk-aligned blocks "
        "(`irdetect.pipeline._Reader`); memory does not depend on the sequence length "
        "(`tests/test_memory.py`). The per-frame tracks, the fusion and the track "
        "initiation run once at the end on the points the windows gave (a few per frame); "
        "they measure each track against the detections of its own span only, so their "
        "memory grows with the detections, not with tracks x detections (until "
        "2026-12-06 it did: 430 MB after 20,000 frames against 304 MB after 1,200).",
        "- Result rows are buffered and written in blocks (`ResultsWriter.append`).",
        "- `--threads N` (`workers=N` of `iter_results` / `process_file`; CLI default 2) "
        "runs suppression to fusion of the next windows and the correlation (with its "
        "verification) of each window triple on N threads; the results are taken up in "
        "order, so every table is the same for any N (`tests/test_memory.py`, "
        "`tests/test_fast.py`, `scripts/check_identity.py`). Each thread holds its own "
        "copy of a window's raw frames and its temporaries, so a second thread costs memory "
        "(see the RSS column).",
        "- The verification's track sums are compiled kernels (numba, "
        "`irdetect/kernels/sampling.py`; they release the GIL, so the correlation thread "
        "and the front-end thread run on both cores): the coarse stage reads one 3 x 3 patch "
        "per frame and lead, the hill climb (at most 108 hypotheses per chain) is one kernel "
        "per chain whose 3 x 3 grids share their rows and columns per frame, and chains are "
        "visited in order of their row so that the frames' rows stay cached. They replaced "
        "one `cv2.remap` per window block with identical tables (`scripts/check_identity.py`). "
        "The per-frame path's local maxima are one compiled pass per frame "
        "(`irdetect/kernels/peaks.py`) instead of a dilation, a comparison and `nonzero`.",
        "- Measured and not adopted (issue 27): row medians and MADs by a compiled "
        "quickselect were 1.9-2.5x slower than numpy's vectorised sort on the 576-1,024-value "
        "rows of the tile statistics (faster only on single rows of 4,000+ values); "
        "visiting the coarse stage's chains frame by frame (one frame in cache, all chains) "
        "gained under 10 % over chains in row order.",
        "- Measured and not adopted: splitting a long sequence into ranges run on 2 "
        "processes (each range computing the 2 windows on either side of it: identical "
        "tables) gave no speed over 2 threads in repeated runs on 4,800 frames of 256x256 "
        "(the code and its numbers: commits df8276a and d43839f): the per-frame stages make "
        "several passes over every frame and "
        "share the memory bandwidth, and a started process pays the interpreter's start-up "
        "again (the difference of the wall and in-run columns above). Since then the "
        "verification has become most of the work, and by hand (2026-12-02, 256x256, 1,200 "
        "frames, whole commands) two independent `irdetect process --threads 1` runs at "
        "once took 3.5-4.2 s against 3.2-3.9 s for one alone and 2.8-3.3 s for one on 2 "
        "threads: about 1.75x one process's frames per second, against 1.15x for a second "
        "thread. Separate inputs get that today (`--out-dir DIR --jobs 2`, docs/batch.md); "
        "one sequence on 2 processes is not back because `auto`'s camera-motion state "
        "carries from window to window (a range would first need the camera pass up to its "
        "start) and 2 processes cannot bring the default within 5x of the floor (issue 19).",
        "- Exact rewrites (bit-identical tables): tile medians by one numpy sort instead of "
        "`np.median`'s partition, fusion by flat candidate indices, no finite check on "
        "integer frames, no per-window concatenations, `auto`'s motion check on the 3 "
        "frames it compares, the fixed-pattern median band by band (16 rows at a time, "
        "made contiguous by `cv2.transpose` and sorted in place: numpy's sort of the "
        "strided view was most of the registered background's time, and the whole "
        "stack's copies its memory), the registered background's sums by `cv2.add` on "
        "the views; the "
        "verification's sampling in float32 with fewer temporaries and larger chunks, the "
        "3 windows' matched frames sampled in place (no stacked copy per triple), the "
        "residuals turned into the matched frames in place, the detector's winning "
        "direction by arithmetic instead of masked stores, the temporal background's "
        "running sum by `cv2.accumulate` (convert and add in one pass).",
        "",
    ]
    return "\n".join(lines)


def footage_report(data: dict) -> list[str]:
    """The markdown of the footage section, with ``data["before_footage"]`` beside it."""
    before = data.get("before_footage")
    old = {r[0]: r for r in before["footage"]} if before else {}
    head = ("| input | frames | size | fps in-run (2 threads) | fps per CPU-second | peak RSS "
            "MB | 1 worker: fps in the stages | suppress share |")
    rule = "|---|---|---|---|---|---|---|---|"
    if before:
        head += (" before: fps in-run | before: fps in the stages | x (stages) | before: peak "
                 "RSS MB | before: suppress share |")
        rule += "---|---|---|---|---|"
    lines = [
        "",
        "## Footage: cluttered and real sequences",
        "",
        "The inputs above have a flat background, on which `auto` keeps the still-camera "
        "background. Cluttered and real footage takes the registered background and its "
        "fixed-pattern estimate (a temporal median of every window's frames). Clutter "
        f"preset: {data['footage'][0][1]} frames of 640x512 uint16 (HDF5, simulated by "
        "this script: clouds, a horizon, hot pixels); the others: the folders of "
        "../shared/data/real (PNG frames, read and decoded in the run). `irdetect process` "
        "with the defaults (2 threads; on these short sequences the in-run seconds include "
        "loading the compiled kernels, about 0.4 s); the stages: `process_file` with 1 "
        "worker, frames per second of their summed seconds and the share of `suppress` in "
        "them.",
    ]
    if before:
        label = f": {before['label']}" if before.get("label") else ""
        untimed = ("" if any("operate" in r[4]["timings"] for r in before["footage"]) else
                   " Its stages leave out `operate` (in no stage then), so the x of the "
                   "stages is a lower bound.")
        lines += ["", f"Before: `{Path(before['path']).name}`, measured on {before['when']} "
                  f"by this script on another checkout (`--footage-only`){label}.{untimed}"]
    lines += ["", head, rule]

    def cells(n, cli, st):
        """fps in-run, fps per CPU-s, RSS, fps in the stages, suppress share."""
        stages = sum(st["timings"].values())
        share = st["timings"].get("suppress", 0.0) / stages if stages > 0 else float("nan")
        return (fps(n, cli["run"]), fps(n, cli["cpu"]), f"{cli['rss_mb']:.0f}",
                fps(n, stages), f"{100 * share:.0f} %")

    for name, n, size, cli, st in data["footage"]:
        line = f"| {name} | {n} | {size} | " + " | ".join(cells(n, cli, st)) + " |"
        if before and name in old:
            _, n_b, _, cli_b, st_b = old[name]
            b = cells(n_b, cli_b, st_b)
            gain = (sum(st_b["timings"].values()) / n_b) / max(
                sum(st["timings"].values()) / n, 1e-12)
            line += f" {b[0]} | {b[3]} | {gain:.2f} | {b[2]} | {b[4]} |"
        elif before:
            line += " | | | | |"
        lines.append(line)
    return lines


def before_after(data: dict) -> list[str]:
    """The markdown comparing this run with ``data["before"]`` (an earlier run's
    measurements): end to end per size and CLI run, and per stage (1 worker)."""
    before, n = data["before"], data["frames"]
    nb = before["frames"]
    lines = [
        "",
        "## Before and after",
        "",
        f"Before: `{Path(before['path']).name}`, measured on {before['when']} by this script "
        f"({nb} frames per size; load average {before['load'][0]:.1f} / "
        f"{before['load'][1]:.1f}). After: this run.",
        "",
        "| frames | run | fps in-run before | after | x | fps per CPU-s before | after | "
        "peak RSS MB before | after |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    old = {(name, label): r for name, _, cli in before["rows"] for label, r in cli.items()}
    for name, _, cli in data["rows"]:
        for label, r in cli.items():
            b = old.get((name, label))
            if b is None:
                continue
            gain = (n / r["run"]) / (nb / b["run"])
            lines.append(f"| {name} | `{label}` | {fps(nb, b['run'])} | {fps(n, r['run'])} | "
                         f"{gain:.2f} | {fps(nb, b['cpu'])} | {fps(n, r['cpu'])} | "
                         f"{b['rss_mb']:.0f} | {r['rss_mb']:.0f} |")
    lines += ["", "Per stage, 1 worker, ms per frame (before -> after):", "",
              "| frames | config | " + " | ".join(STAGES) + " | total |",
              "|---|---|" + "---|" * (len(STAGES) + 1)]
    old_st = {(name, label): st for name, label, w, st in before["stage_rows"] if w == 1}
    for name, label, workers, st in data["stage_rows"]:
        b = old_st.get((name, label))
        if workers != 1 or b is None:
            continue
        cells = [f"{1e3 * b['timings'].get(k, 0.0) / nb:.2f} -> "
                 f"{1e3 * st['timings'].get(k, 0.0) / n:.2f}" for k in STAGES]
        total = (f"{1e3 * sum(b['timings'].values()) / nb:.2f} -> "
                 f"{1e3 * sum(st['timings'].values()) / n:.2f}")
        lines.append(f"| {name} | {label} | " + " | ".join(cells) + f" | {total} |")
    return lines


def _cv2_version() -> str:
    import cv2
    return cv2.__version__


if __name__ == "__main__":
    sys.exit(main())
