"""Annotated video export: read the output back with OpenCV and check what was drawn where.

The results files are written here from the simulated truth (detections at the targets'
mid-window positions, tracks along their true paths), so the place of every overlay is
known exactly.
"""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from irdetect import tables
from irdetect.errors import InputError
from irdetect.io import ResultsWriter, open_sequence, read_results, write_sequence
from irdetect.io.video import VideoWriter, output_kind
from irdetect.render import (COLOURS, Overlay, Style, display_limits, draw_overlay, stretch,
                             window_colour, write_video)
from irdetect.simulate import simulate

L = 12            # frames per combined frame
T, H, W = 36, 40, 56
SCALE = 2.0


def _truth_results(truth, *, n_frames=T, height=H, width=W, tracks=True, track_points=False):
    """Tables drawn from truth: one detection per target per window (position at the
    window's middle frame), and one track per target over frames 12..35."""
    det = []
    for k in range(n_frames // L):
        mid = k * L + L // 2
        rows = truth[truth["frame"] == mid]
        det.append(tables.from_columns(
            tables.DETECTION, x=rows["x"], y=rows["y"], frame_start=np.full(len(rows), k * L),
            frame_end=np.full(len(rows), k * L + L - 1), combined_frame=np.full(len(rows), k),
            intensity=np.ones(len(rows)), score=np.ones(len(rows))))
    found = {"detections": np.concatenate(det), "candidates": tables.empty("candidates"),
             "segments": tables.empty("segments"), "tracks": tables.empty("tracks")}
    if tracks:
        rows = []
        for tid in np.unique(truth["target"]):
            tr = truth[truth["target"] == tid]
            a, b = tr[tr["frame"] == L][0], tr[tr["frame"] == n_frames - 1][0]
            n = n_frames - 1 - L
            rows.append(tables.from_columns(
                tables.TRACK, track_id=[tid], x0=[a["x"]], y0=[a["y"]],
                vx=[(b["x"] - a["x"]) / n], vy=[(b["y"] - a["y"]) / n], frame_start=[L],
                frame_end=[n_frames - 1], n_points=[2], score=[1.0], rho=[0.0], theta=[0.0]))
        found["tracks"] = np.concatenate(rows)
    if track_points:
        found["track_points"] = tables.from_columns(
            tables.TRACK_POINT, frame=truth["frame"], track_id=truth["target"] + 100,
            x=truth["x"], y=truth["y"])
    attrs = {"input": "seq.h5", "combined_length": L, "n_frames": n_frames,
             "frame_height": height, "frame_width": width, "config": "{}"}
    return found, attrs


def _write_results(path, found, attrs):
    with ResultsWriter(path, attrs=attrs) as out:
        for name, table in found.items():
            out.write(name, table)
    return path


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A simulated sequence (2 targets) and a results file drawn from its truth."""
    folder = tmp_path_factory.mktemp("scene")
    frames, truth = simulate("wan2008", rng=5, n_frames=T, height=H, width=W, n_targets=2,
                             snr=6.0, speed=[0.5, 0.8], directions=[20.0, 200.0])
    seq = write_sequence(folder / "seq.h5", frames, truth=truth, attrs={"frame_rate": 20.0})
    found, attrs = _truth_results(truth)
    res = _write_results(folder / "res.h5", found, attrs)
    return {"seq": seq, "res": res, "frames": frames, "truth": truth, "found": found,
            "folder": folder}


def _read_png_folder(folder):
    names = sorted(os.listdir(folder))
    return names, [cv2.imread(str(folder / n)) for n in names]


def _read_video(path):
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(frame)
    fps = cap.get(cv2.CAP_PROP_FPS)
    cap.release()
    return out, fps


def _colourful(img, spread=60):
    """Pixels that are clearly coloured (the raw frame is grey: B = G = R)."""
    img = img.astype(int)
    return (img.max(axis=2) - img.min(axis=2)) > spread


def _near(shape, points, radius):
    """Mask of output pixels within ``radius`` of any of the (output px) points."""
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    mask = np.zeros(shape, bool)
    for x, y in points:
        mask |= np.hypot(xx - x, yy - y) <= radius
    return mask


def _det_px(found, t, scale=SCALE):
    """Output-pixel positions of the detections shown at frame t, and their rows."""
    det = found["detections"]
    det = det[(det["frame_start"] <= t) & (det["frame_end"] >= t)]
    return [((x + 0.5) * scale - 0.5, (y + 0.5) * scale - 0.5)
            for x, y in zip(det["x"], det["y"])], det


def test_png_folder_draws_detections_exactly_where_they_are(scene, tmp_path):
    res = read_results(scene["res"])
    res.tables["tracks"] = tables.empty("tracks")          # detections only
    out = tmp_path / "frames"
    with open_sequence(scene["seq"]) as src:
        summary = write_video(src, res, out, scale=SCALE, legend=False)
    names, images = _read_png_folder(out)
    assert summary["frames"] == T == len(images)
    assert names[0] == "frame_000000.png" and names[-1] == f"frame_{T - 1:06d}.png"
    radius = max(3.0 * SCALE, 5.0)
    for t, img in enumerate(images):
        assert img.shape == (H * SCALE, W * SCALE, 3)
        points, det = _det_px(scene["found"], t)
        colour = _colourful(img)
        # present: every detection has a ring of its window's colour around it
        for (x, y), k in zip(points, det["combined_frame"]):
            ring = _near(colour.shape, [(x, y)], radius + 1.5) & ~_near(colour.shape, [(x, y)],
                                                                       radius - 1.5)
            hit = ring & colour
            assert hit.sum() > 10, f"frame {t}: no circle around ({x:.1f}, {y:.1f})"
            mean = img[hit].mean(axis=0)
            assert np.abs(mean - np.array(window_colour(k))).max() < 90
        # absent elsewhere
        # (a 2-px line, anti-aliased, reaches radius + 2.5)
        assert not (colour & ~_near(colour.shape, points, radius + 3)).any(), f"frame {t}"


@pytest.mark.parametrize("suffix", [".mp4", ".avi"])
def test_video_file_reads_back_with_count_size_and_colour(scene, tmp_path, suffix):
    # scale 4 (224 x 160 px): mp4v's rate control bleaches thin coloured lines in
    # tiny frames; the CLI's default scale gives at least 640 px width
    scale = 4.0
    res = read_results(scene["res"])
    res.tables["tracks"] = tables.empty("tracks")
    out = tmp_path / f"out{suffix}"
    with open_sequence(scene["seq"]) as src:
        write_video(src, res, out, scale=scale, legend=False)
    frames, fps = _read_video(out)
    assert len(frames) == T
    assert frames[0].shape == (H * scale, W * scale, 3)
    assert fps == pytest.approx(20.0)                     # the sequence's frame rate
    radius = 3.0 * scale
    for t in (0, 17, T - 1):
        points, _ = _det_px(scene["found"], t, scale)
        colour = _colourful(frames[t], spread=80)
        for x, y in points:
            assert (colour & _near(colour.shape, [(x, y)], radius + 3)).sum() > 50
        near = _near(colour.shape, points, radius + 4)
        assert (colour & ~near).sum() <= 5                # lossy codec: a stray pixel or two


def test_png_frames_match_the_video_frame_by_frame(scene, tmp_path):
    with open_sequence(scene["seq"]) as src:
        res = read_results(scene["res"])
        write_video(src, res, tmp_path / "png", scale=SCALE)
        write_video(src, res, tmp_path / "v.avi", scale=SCALE)
    _, pngs = _read_png_folder(tmp_path / "png")
    video, _ = _read_video(tmp_path / "v.avi")
    assert len(pngs) == len(video) == T
    for t, frame in enumerate(video):
        assert frame.shape == pngs[t].shape
        diffs = [np.abs(frame.astype(int) - p.astype(int)).mean() for p in pngs]
        assert int(np.argmin(diffs)) == t
        assert diffs[t] < 8.0


def _has(img, bgr, tol=40):
    """Mask of the pixels of colour ``bgr`` (within ``tol`` per channel)."""
    return np.abs(img.astype(int) - np.array(bgr)).max(axis=2) < tol


def test_tracks_only_over_the_frames_they_span_and_truth_in_green(scene, tmp_path):
    out = tmp_path / "frames"
    with open_sequence(scene["seq"]) as src:
        write_video(src, read_results(scene["res"]), out, scale=SCALE, legend=False,
                    truth=src.truth)
    _, images = _read_png_folder(out)
    for t, img in enumerate(images):
        orange = _has(img, COLOURS["track"]).sum()
        if t < L:
            assert orange == 0, f"track drawn at frame {t}, before it starts"
        else:
            assert orange > 20, f"track missing at frame {t}"
        assert _has(img, COLOURS["truth"]).sum() > 4


def test_track_points_are_drawn_when_present(scene, tmp_path):
    found, attrs = _truth_results(scene["truth"], tracks=False, track_points=True)
    res = _write_results(tmp_path / "tp.h5", found, attrs)
    out = tmp_path / "frames"
    with open_sequence(scene["seq"]) as src:
        write_video(src, read_results(res), out, scale=SCALE, every=7)
    names, images = _read_png_folder(out)
    assert names == [f"frame_{t:06d}.png" for t in range(0, T, 7)]
    for img in images:
        yellow = np.abs(img.astype(int) - np.array(COLOURS["tracker"])).max(axis=2) < 40
        assert yellow.sum() > 10


def test_results_without_tracks_still_give_a_video(scene, tmp_path):
    found, attrs = _truth_results(scene["truth"], tracks=False)
    found["detections"] = tables.empty("detections")
    res = _write_results(tmp_path / "empty.h5", found, attrs)
    with open_sequence(scene["seq"]) as src:
        summary = write_video(src, read_results(res), tmp_path / "out.mp4", panels=True)
    frames, _ = _read_video(tmp_path / "out.mp4")
    assert summary["frames"] == len(frames) == T
    assert summary["size"][0] == frames[0].shape[1]


def test_panels_show_raw_suppressed_and_combined(scene, tmp_path):
    with open_sequence(scene["seq"]) as src:
        summary = write_video(src, read_results(scene["res"]), tmp_path / "p", scale=1.0,
                              panels=True, legend=False, every=6)
    _, images = _read_png_folder(tmp_path / "p")
    assert len(images) == T // 6
    assert images[0].shape[1] == summary["size"][0] == 3 * W + 8

    def split(img):
        return img[:, :W], img[:, W + 4:2 * W + 4], img[:, 2 * W + 8:]

    (raw0, sup0, comb0), (raw6, sup6, comb6) = split(images[0]), split(images[1])
    body = (slice(12, None), slice(None))                 # below the panel titles
    # frames 0 and 6 share one combined frame but not their raw / suppressed frames
    assert np.array_equal(comb0[body], comb6[body])
    assert not np.array_equal(sup0[body], sup6[body])
    assert not np.array_equal(raw0[body], sup0[body])
    # the panels are the suppressor's residual and its combined frame (the default
    # projection of irdetect.combine, as the results hold no config), recomputed here
    from irdetect.combine import combine
    from irdetect.suppress import suppress

    residual = suppress(scene["frames"][:L].astype(np.float32))
    want_sup = stretch(residual)[6]
    want_comb = stretch(combine(residual, length=L)[0])
    grey = split(~_colourful(images[1], spread=0))        # pixels without an overlay
    for got, want, g in ((sup6, want_sup, grey[1]), (comb6, want_comb, grey[2])):
        g = g & (np.arange(H) >= 20)[:, None]             # below the panel title
        bad = (np.abs(got[..., 0].astype(int) - want.astype(int)) > 1) & g; print(got[25, :12, 0], want[25, :12], np.array_equal(scene["frames"][:L], open_sequence(scene["seq"])[0:L]))
        assert np.abs(got[..., 0].astype(int) - want.astype(int))[g].max() <= 1


@pytest.mark.parametrize("kind", ["frames", "size", "extent"])
def test_results_of_another_sequence_fail_before_any_frame(scene, tmp_path, kind):
    truth = scene["truth"]
    if kind == "frames":
        found, attrs = _truth_results(truth, n_frames=T)
        attrs["n_frames"] = 48
    elif kind == "size":
        found, attrs = _truth_results(truth)
        attrs["frame_width"] = 320
    else:                             # no size attributes, but points outside the frame
        found, attrs = _truth_results(truth)
        for key in ("n_frames", "frame_height", "frame_width"):
            del attrs[key]
        found["detections"]["x"] += W
    res = _write_results(tmp_path / "other.h5", found, attrs)
    out = tmp_path / "out.mp4"
    with open_sequence(scene["seq"]) as src:
        with pytest.raises(InputError, match="another sequence"):
            write_video(src, read_results(res), out)
    assert os.listdir(tmp_path) == ["other.h5"]          # nothing written, no temp file


def test_cli_video_and_its_bad_input(scene, cli, tmp_path):
    seq, res = scene["seq"], scene["res"]
    code, _, err = cli("video", seq, res, "-o", "a.mp4", "--truth", "--candidates")
    assert code == 0, err
    assert len(_read_video(tmp_path / "a.mp4")[0]) == T
    code, _, err = cli("video", seq, res, "-o", "a.mp4")
    assert code == 2 and "--force" in err
    code, _, err = cli("video", seq, res, "-o", "a.gif")
    assert code == 2 and "unknown video output type" in err and "Traceback" not in err
    code, _, err = cli("video", seq, res, "-o", "missing/a.mp4")
    assert code == 2 and "does not exist" in err
    code, _, err = cli("video", seq, res, "-o", "b.mp4", "--every", "0")
    assert code == 2 and "--every" in err
    code, _, err = cli("video", seq, tmp_path / "nope.h5", "-o", "b.mp4")
    assert code == 2 and "not found" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mp4"]


def test_the_sequence_alone_with_its_truth_before_any_run(scene, cli, tmp_path):
    """Without a results file: every frame, the truth in green at its place, nothing
    else drawn, and the same size as with results."""
    code, _, err = cli("video", scene["seq"], "-o", "alone", "--truth", "--scale", "2")
    assert code == 0, err
    _, images = _read_png_folder(tmp_path / "alone")
    assert len(images) == T
    with open_sequence(scene["seq"]) as src:
        truth = src.truth
    for t in (0, T // 2, T - 1):
        green = _has(images[t][:H * 2], COLOURS["truth"])     # above the status strip
        rows = truth[truth["frame"] == t]
        near = _near(green.shape, np.column_stack([rows["x"], rows["y"]]) * 2 + 0.5, 12)
        assert green.sum() > 4 and not (green & ~near).any(), t
        assert not _has(images[t], COLOURS["track"]).any()
    code, _, err = cli("video", scene["seq"], scene["res"], "-o", "with", "--scale", "2")
    assert code == 0, err
    assert _read_png_folder(tmp_path / "with")[1][0].shape == images[0].shape


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0,
                    reason="root can write into read-only folders")
def test_unwritable_folder_is_refused(scene, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(InputError, match="not writable"):
            VideoWriter(ro / "a.mp4")
    finally:
        ro.chmod(0o700)


def test_png_folder_is_replaced_only_with_force_and_only_if_it_holds_frames(tmp_path):
    out = tmp_path / "frames"
    frame = np.zeros((6, 8, 3), np.uint8)
    for value in (10, 200):
        force = value == 200
        with VideoWriter(out, force=force) as w:
            w.write(frame + value)
    assert os.listdir(out) == ["frame_000000.png"]
    assert cv2.imread(str(out / "frame_000000.png"))[0, 0, 0] == 200
    (out / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="other than PNG"):
        VideoWriter(out, force=True)
    assert (out / "notes.txt").exists()


def test_failed_run_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with VideoWriter(tmp_path / "a.mp4") as w:
            w.write(np.zeros((6, 8, 3), np.uint8))
            raise RuntimeError("killed")
    assert os.listdir(tmp_path) == []


def test_odd_sizes_are_padded_for_video(tmp_path):
    with VideoWriter(tmp_path / "a.avi", fps=5) as w:
        for i in range(3):
            w.write(np.full((7, 9), 40 * i, np.uint8))
    frames, fps = _read_video(tmp_path / "a.avi")
    assert len(frames) == 3 and frames[0].shape == (8, 10, 3) and fps == pytest.approx(5)


@pytest.mark.parametrize("path,kind", [("a.mp4", "mp4"), ("a.AVI", "avi"), ("frames", "png"),
                                       ("frames/", "png")])
def test_output_kind(path, kind):
    assert output_kind(path) == kind


def test_stretch_is_robust_and_16_bit_aware():
    rng = np.random.default_rng(0)
    frame = (1000 + rng.normal(0, 10, (64, 64))).astype(np.uint16)
    frame[5, 5] = 65535                                    # a hot pixel
    out = stretch(frame)
    assert out.dtype == np.uint8 and out.shape == frame.shape
    # the hot pixel does not squeeze the scene into a few grey levels
    assert np.percentile(out, 90) - np.percentile(out, 10) > 100
    lo, hi = display_limits(frame)
    assert 950 < lo < 1000 < hi < 1050
    # the same mapping for float input, and gamma < 1 brightens mid-tones
    assert np.array_equal(stretch(frame.astype(np.float32), limits=(lo, hi)),
                          stretch(frame, limits=(lo, hi)))
    assert stretch(frame, limits=(lo, hi), gamma=0.5).mean() > out.mean()
    nan = np.full((4, 4), np.nan, np.float32)
    nan[0, 0] = 1.0
    assert stretch(nan).max() <= 255
    with pytest.raises(ValueError, match="gamma"):
        stretch(frame, gamma=0)


def test_overlay_position_follows_the_pixel_centre_convention():
    det = tables.from_columns(tables.DETECTION, x=[10.0], y=[4.0], frame_start=[0],
                              frame_end=[11], combined_frame=[0])
    ov = Overlay.from_tables({"detections": det})
    img = np.zeros((40, 60, 3), np.uint8)
    draw_overlay(img, 5, ov, Style(scale=3.0, radius=2.0))
    yy, xx = np.nonzero(img.max(axis=2) > 0)
    cx, cy = (10 + 0.5) * 3 - 0.5, (4 + 0.5) * 3 - 0.5
    assert abs(xx.mean() - cx) < 0.6 and abs(yy.mean() - cy) < 0.6
    img2 = np.zeros_like(img)
    draw_overlay(img2, 12, ov, Style(scale=3.0))          # outside the window: nothing
    assert not img2.any()


def test_process_writes_the_video_after_the_results(scene, cli, tmp_path):
    (tmp_path / "taken.avi").write_bytes(b"")
    code, _, err = cli("process", scene["seq"], "-o", "r.h5", "--video", "taken.avi")
    assert code == 2 and "--force" in err
    assert not (tmp_path / "r.h5").exists()               # refused before processing
    code, _, err = cli("process", scene["seq"], "-o", "r.h5", "--video", "v.avi", "--every", "2")
    assert code == 0, err
    frames, _ = _read_video(tmp_path / "v.avi")
    assert len(frames) == T // 2 and (tmp_path / "r.h5").exists()


def test_the_excluded_pixels_are_outlined(scene, tmp_path):
    """A run's ``exclude`` rectangle is drawn as an outline in its colour, on its border
    and nowhere else; a mask image that has since gone is a warning, not an error."""
    import json

    found, attrs = _truth_results(scene["truth"], tracks=False)
    found["detections"] = tables.empty("detections")
    res = _write_results(tmp_path / "res.h5",
                         found, {**attrs, "config": json.dumps({"exclude": ["10,20,30,35"]})})
    with open_sequence(scene["seq"]) as src:
        write_video(src, read_results(res), tmp_path / "png", scale=1.0, legend=False)
    _, images = _read_png_folder(tmp_path / "png")
    img = images[0].astype(int)
    drawn = np.abs(img - np.array(COLOURS["excluded"])).sum(axis=2) < 40
    border = np.zeros((H, W), bool)
    border[20:35, 10:30] = True
    border[21:34, 11:29] = False
    assert drawn[border].mean() > 0.9 and not drawn[~border].any()
    gone = _write_results(tmp_path / "gone.h5", found,
                          {**attrs, "config": json.dumps({"exclude": [str(tmp_path / "x.png")]})})
    with open_sequence(scene["seq"]) as src:
        assert write_video(src, read_results(gone), tmp_path / "png2", scale=1.0)["frames"] == T


def test_each_frame_shows_one_window_where_windows_overlap(tmp_path):
    # 41 frames: windows 0-2 every 12 frames and the tail window 3 over frames 29-40;
    # frames 29-35 lie in windows 2 and 3, and show the window whose middle is nearer
    from irdetect.render import shown_windows

    n = 41
    shown = shown_windows(n, [0, 12, 24, 29], L)
    assert shown[:29].tolist() == [0] * 12 + [1] * 12 + [2] * 5
    assert shown[29:33].tolist() == [2] * 4 and shown[33:].tolist() == [3] * 8
    assert shown_windows(40, [0, 12, 24], L)[36:].tolist() == [-1] * 4   # in no window
    frames, truth = simulate("wan2008", rng=5, n_frames=n, height=H, width=W, n_targets=1,
                             snr=6.0, speed=[0.5, 0.5], directions=[20.0])
    seq = write_sequence(tmp_path / "seq.h5", frames, truth=truth)
    det = tables.from_columns(
        tables.DETECTION, x=[20.0, 24.0, 28.0, 30.0], y=[20.0] * 4,
        frame_start=[0, 12, 24, 29], frame_end=[11, 23, 35, 40], combined_frame=[0, 1, 2, 3],
        intensity=np.ones(4), score=np.ones(4))
    found = {"detections": det, "candidates": tables.empty("candidates"),
             "segments": tables.empty("segments"), "tracks": tables.empty("tracks")}
    attrs = {"input": "seq.h5", "combined_length": L, "combined_step": L, "n_frames": n,
             "frame_height": H, "frame_width": W, "config": '{"combine": {"tail": true}}'}
    res = read_results(_write_results(tmp_path / "res.h5", found, attrs))
    out = tmp_path / "frames"
    with open_sequence(seq) as src:
        write_video(src, res, out, scale=SCALE, legend=False)
    _, images = _read_png_folder(out)
    for t, k in ((30, 2), (34, 3)):
        colour = _colourful(images[t])
        x = det["x"][k]
        here = _near(colour.shape, [((x + 0.5) * SCALE - 0.5, (20 + 0.5) * SCALE - 0.5)], 9)
        other = 5 - k                          # the other window of the two
        there = _near(colour.shape, [((det["x"][other] + 0.5) * SCALE - 0.5,
                                      (20 + 0.5) * SCALE - 0.5)], 9)
        assert (colour & here).sum() > 10, f"frame {t}: window {k}'s detection not drawn"
        assert not (colour & there & ~here).any(), f"frame {t}: window {other}'s drawn too"
