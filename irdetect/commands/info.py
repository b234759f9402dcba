"""Say what a sequence, scans or results file holds, in a few lines."""

from __future__ import annotations

import json
from pathlib import Path

import h5py

from irdetect.commands import DATASET_HELP, SEQUENCE_KINDS
from irdetect.errors import InputError, check_input_file
from irdetect.io import open_sequence, read_point_annotations, read_results
from irdetect.io.sources import LOSSY_CODECS
from irdetect.io.truth import recording_truth

RESULT_TABLES = ("detections", "candidates", "segments", "tracks", "track_points", "scans")


def add_arguments(p):
    p.add_argument("file", help=f"sequence ({SEQUENCE_KINDS}), scans or results")
    p.add_argument("--dataset", help=DATASET_HELP)


def describe(path, dataset=None) -> list[str]:
    """Human lines describing ``path``; raises InputError when it cannot be read."""
    p = Path(path)
    if not p.is_dir():
        check_input_file(p)
    if h5py.is_hdf5(p):
        try:
            with h5py.File(p, "r") as f:
                is_results = dataset is None and any(name in f for name in RESULT_TABLES)
                # a scans file (/scans, maybe /truth) is input, not results
                is_scans = is_results and not any(n in f for n in RESULT_TABLES
                                                  if n != "scans")
        except OSError as exc:
            raise InputError(f"corrupt or truncated HDF5 file ({str(exc).splitlines()[0]})",
                             path) from None
        if is_scans:
            from irdetect.io.scans import describe_scans
            return describe_scans(path)
        if is_results:
            return _describe_results(path)
    with open_sequence(path, dataset) as src:
        t, h, w = src.shape
        first = src[0]
        lines = [f"{path}: image sequence ({type(src).__name__[:-6]})",
                 f"  {t} frames of {w}x{h} px (W x H), {src.stored_dtype}"
                 + (f" (read as {src.dtype})" if src.dtype != src.stored_dtype else ""),
                 f"  frame 0 values {first.min()}..{first.max()}"]
        if src.frame_rate:
            lines.append(f"  frame rate {src.frame_rate:g} Hz")
        if src.codec:
            lines.append(f"  codec {src.codec}" + (
                ": lossy, a still scene's faint structure changes in steps that can read as "
                "dim slow targets; prefer the sensor's own frames (docs/real.md, \"The "
                "sequences compressed\")" if src.codec in LOSSY_CODECS else ""))
        if src.truth is not None:
            targets = len(set(src.truth["target"].tolist()))
            lines.append(f"  truth: {len(src.truth)} rows, {targets} target(s)")
        elif (found := recording_truth(src.path)) is not None:
            # what evaluate, video and plot take as its truth without --truth
            try:
                n = len(read_point_annotations(found, t))
                lines.append(f"  truth: {found}, {n} positions of one target")
            except InputError as exc:
                lines.append(f"  truth: {found} unusable: {exc.message}")
    return lines


def _describe_results(path) -> list[str]:
    res = read_results(path)
    tracks = res.tables.get("tracks", res.tables.get("scan_tracks"))
    kind = ("irdetect results of initiate on scans"
            if tracks is not None and "scan_start" in tracks.dtype.names else "irdetect results")
    lines = [f"{path}: {kind} (version {res.attrs.get('irdetect_version', '?')})"]
    if "input" in res.attrs:
        lines.append(f"  input {res.attrs['input']}")
    for name, table in res.tables.items():
        lines.append(f"  /{name}: {len(table)} rows ({', '.join(table.dtype.names)})")
    if "combined_length" in res.attrs:
        line = f"  combined frames of {res.attrs['combined_length']} frames"
        if {"combined_step", "n_frames"} <= set(res.attrs):
            line += _windows(int(res.attrs["n_frames"]), *res.windows())
        if res.attrs.get("short_sequence"):
            line += (f" (a short sequence of {res.attrs.get('n_frames', '?')} frames: "
                     f"{res.attrs.get('configured_length', '?')} configured)")
        lines.append(line)
    if "config" in res.attrs:
        changed = config_changes(res.config)
        lines.append("  config: the defaults" if not changed else
                     f"  config, where not the defaults: {', '.join(changed)}")
    return lines


def _windows(n_frames: int, length: int, step: int, tail: bool) -> str:
    """How the combined frames lie in the sequence: ", 3 every 12 frames from frame 0
    and the tail window over frames 29-40", or which last frames are in none."""
    from irdetect.combine import window_starts

    regular = window_starts(n_frames, length=length, step=step)
    text = f", {len(regular)} every {step} frames from frame 0"
    if len(window_starts(n_frames, length=length, step=step, tail=tail)) > len(regular):
        return text + f" and the tail window over frames {n_frames - length}-{n_frames - 1}"
    if len(regular) and regular[-1] + length < n_frames:
        return text + f" (frames {regular[-1] + length}-{n_frames - 1} in none)"
    return text


def config_changes(config: dict) -> list[str]:
    """``section.key = value (default d)`` for each setting of a results file's
    configuration (JSON, ``to_json``) that differs from ``ProcessConfig()``'s; settings
    without a default (another release's) are given as they are."""
    from irdetect.config import ProcessConfig, to_json

    defaults = json.loads(to_json(ProcessConfig()))
    out = []
    for section, values in sorted(config.items()):
        if not isinstance(values, dict):
            if values != defaults.get(section):
                out.append(f"{section} = {json.dumps(values)}")
            continue
        known = defaults.get(section, {})
        for key, value in sorted(values.items()):
            if key not in known:
                out.append(f"{section}.{key} = {json.dumps(value)}")
            elif value != known[key]:
                out.append(f"{section}.{key} = {json.dumps(value)} "
                           f"(default {json.dumps(known[key])})")
    return out


def run(args) -> int:
    print("\n".join(describe(args.file, args.dataset)))
    return 0
