"""The foundation's CLI: simulate, convert, info, and every bad input of issue 2."""

import h5py
import numpy as np
import pytest

from tests.conftest import real_sequence


def test_simulate_then_info(cli):
    code, _, err = cli("simulate", "s.h5", "--seed", "1", "--frames", "20", "--snr", "5")
    assert code == 0, err
    code, out, _ = cli("info", "s.h5")
    assert code == 0
    assert "20 frames of 320x240" in out and "5 target(s)" in out


def test_info_names_a_recording_folders_truth_and_says_when_it_does_not_fit(cli, tmp_path):
    import cv2

    rec = tmp_path / "rec"
    (rec / "frames").mkdir(parents=True)
    for i in range(5):
        cv2.imwrite(str(rec / "frames" / f"{i:03d}.png"), np.full((16, 20), 40 + i, np.uint8))
    (rec / "truth.txt").write_text("".join(f"{3 + i} 4\n" for i in range(5)))
    for where in (rec, rec / "frames"):            # the recording folder or its frames
        code, out, _ = cli("info", where)
        assert code == 0
        assert f"truth: {rec / 'truth.txt'}, 5 positions of one target" in out
    (rec / "truth.txt").write_text("3 4\n" * 4)    # a line short
    code, out, _ = cli("info", rec)
    assert code == 0 and "unusable: 4 annotation lines for 5 frames" in out


def test_info_on_results_names_the_settings_that_are_not_the_defaults(cli, tmp_path):
    assert cli("simulate", "s.h5", "--seed", "1", "--frames", "36", "--size", "64x48")[0] == 0
    assert cli("process", "s.h5", "-o", "a.h5", "-q")[0] == 0
    (tmp_path / "c.toml").write_text('[suppress]\nmethod = "temporal"\n'
                                     '[frame]\nenabled = false\n')
    assert cli("process", "s.h5", "-o", "b.h5", "-q", "--config", "c.toml")[0] == 0
    assert "  config: the defaults" in cli("info", "a.h5")[1].splitlines()
    line = cli("info", "b.h5")[1].splitlines()[-1]
    assert line == ('  config, where not the defaults: frame.enabled = false (default true), '
                    'suppress.method = "temporal" (default "auto")')


def test_info_on_results_says_where_the_combined_frames_lie(cli, tmp_path):
    assert cli("simulate", "s.h5", "--seed", "1", "--frames", "41", "--size", "64x48")[0] == 0
    assert cli("process", "s.h5", "-o", "a.h5", "-q")[0] == 0
    (tmp_path / "c.toml").write_text("[combine]\ntail = false\n")
    assert cli("process", "s.h5", "-o", "b.h5", "-q", "--config", "c.toml")[0] == 0
    assert ("  combined frames of 12 frames, 3 every 12 frames from frame 0 and the tail "
            "window over frames 29-40") in cli("info", "a.h5")[1].splitlines()
    assert ("  combined frames of 12 frames, 3 every 12 frames from frame 0 (frames 36-40 "
            "in none)") in cli("info", "b.h5")[1].splitlines()


def test_version_and_help(cli, capsys):
    with pytest.raises(SystemExit) as exc:
        cli("--version")
    assert exc.value.code == 0
    assert "irdetect" in capsys.readouterr().out


def test_convert_real_easy1(cli, tmp_path):
    folder = real_sequence("easy1")
    code, _, err = cli("convert", folder / "frames", "-o", "e.h5", "--truth", folder / "truth.txt")
    assert code == 0, err
    with h5py.File(tmp_path / "e.h5") as f:
        assert f["frames"].shape == (40, 128, 128)
        assert f["truth"].shape == (40,)
        assert f["truth"]["x"][0] == pytest.approx(53.98)


def _bad_inputs(tmp):
    """(name, argv) pairs that must each end with exit code 2 and one line."""
    (tmp / "notes.h5").write_text("not hdf5")
    with h5py.File(tmp / "good.h5", "w") as f:
        f["frames"] = np.zeros((4, 8, 8), np.uint8)
    data = (tmp / "good.h5").read_bytes()
    (tmp / "trunc.h5").write_bytes(data[: len(data) // 2])
    with h5py.File(tmp / "no3d.h5", "w") as f:
        f["x"] = np.zeros((8, 8))
    with h5py.File(tmp / "two3d.h5", "w") as f:
        f["a"] = np.zeros((2, 8, 8))
        f["b"] = np.zeros((2, 8, 8))
    with h5py.File(tmp / "ndim.h5", "w") as f:
        f["frames"] = np.zeros((2, 8, 8, 3))
    with h5py.File(tmp / "zero.h5", "w") as f:
        f["frames"] = np.zeros((0, 8, 8))
    with h5py.File(tmp / "bool.h5", "w") as f:
        f["frames"] = np.zeros((2, 8, 8), bool)
    with h5py.File(tmp / "complex.h5", "w") as f:
        f["frames"] = np.zeros((2, 8, 8), np.complex64)
    nan = np.zeros((3, 8, 8), np.float32)
    nan[2, 1, 1] = np.nan
    np.save(tmp / "nan.npy", nan)
    (tmp / "mixed").mkdir()
    import cv2
    cv2.imwrite(str(tmp / "mixed" / "1.png"), np.zeros((8, 8), np.uint8))
    cv2.imwrite(str(tmp / "mixed" / "2.png"), np.zeros((9, 8), np.uint8))
    (tmp / "ann.txt").write_text("1 2\n3 4\n")
    (tmp / "cfg.toml").write_text("[combine]\nlenght = 12\n")
    # values the stages refuse (checked before the run: each failed mid-run before)
    (tmp / "range.toml").write_text("[correlate]\nscreen = 2.0\n")
    (tmp / "range2.toml").write_text("[detect]\nk = -1.0\n")
    (tmp / "range3.toml").write_text("[initiate]\nq1 = 3.0\n")
    return {
        "missing file": ["info", "nope.h5"],
        "not hdf5": ["info", "notes.h5"],
        "truncated hdf5": ["convert", "trunc.h5", "-o", "o1.h5"],
        "no 3-D dataset": ["info", "no3d.h5"],
        "several 3-D datasets": ["info", "two3d.h5"],
        "wrong ndim": ["info", "ndim.h5"],
        "0 frames": ["info", "zero.h5"],
        "bool dtype": ["info", "bool.h5"],
        "complex dtype": ["info", "complex.h5"],
        "NaN values": ["convert", "nan.npy", "-o", "o2.h5"],
        "mixed sizes": ["convert", "mixed", "-o", "o3.h5"],
        "annotation count": ["convert", "good.h5", "-o", "o4.h5", "--truth", "ann.txt"],
        "unknown config key": ["process", "good.h5", "--config", "cfg.toml", "-o", "o5.h5"],
        "config value out of range": ["process", "good.h5", "--config", "range.toml",
                                      "-o", "o8.h5"],
        "config value out of range 2": ["process", "good.h5", "--config", "range2.toml",
                                        "-o", "o9.h5"],
        "config value out of range 3": ["process", "good.h5", "--config", "range3.toml",
                                        "-o", "o10.h5"],
        "missing output folder": ["convert", "good.h5", "-o", "nowhere/o6.h5"],
        "output exists": ["convert", "good.h5", "-o", "good.h5"],
        "unknown scenario": ["simulate", "o7.h5", "--scenario", "mars"],
    }


def test_every_bad_input_gives_exit_2_one_line_and_no_output(cli, tmp_path):
    cases = _bad_inputs(tmp_path)
    before = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    for name, argv in cases.items():
        code, out, err = cli(*argv)
        assert code == 2, f"{name}: exit {code}, {err}"
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in err, f"{name}: {err}"
        assert lines[0].startswith("irdetect "), name
    after = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    assert after == before  # nothing written, nothing overwritten, no temp files left


def test_messages_name_the_problem_and_the_file(cli, tmp_path):
    cases = _bad_inputs(tmp_path)
    expect = {"annotation count": ("2 annotation lines for 4 frames", "ann.txt"),
              "unknown config key": ("combine.lenght", "cfg.toml"),
              "config value out of range": ("screen must be", "range.toml"),
              "config value out of range 3": ("q1 must", "range3.toml"),
              "0 frames": ("0 frames", "zero.h5"),
              "mixed sizes": ("mixed sizes", "mixed"),
              "NaN values": ("NaN", "nan.npy"),
              "several 3-D datasets": ("--dataset", "two3d.h5"),
              "missing output folder": ("does not exist", "nowhere"),
              "truncated hdf5": ("HDF5", "trunc.h5")}
    for name, (problem, file_name) in expect.items():
        _, _, err = cli(*cases[name])
        assert problem in err and file_name in err, f"{name}: {err}"


def test_simulate_dispatches_on_the_preset_kind(cli):
    code, _, err = cli("simulate", "h.h5", "--scenario", "harbour", "--frames", "30",
                       "--seed", "1")
    assert code == 0, err
    code, out, _ = cli("info", "h.h5")
    assert "30 frames of 320x240" in out
    code, _, err = cli("simulate", "z.h5", "--scenario", "zhang2010")
    assert code == 2 and "simulate-scans" in err


def test_process_and_evaluate_a_recording_folder(cli, tmp_path):
    """A folder with frames/ and truth.txt (the shared/data/real layout) needs no options."""
    import cv2

    from irdetect.simulate import simulate

    frames, truth = simulate("wan2008", rng=2, snr=8, n_frames=36, height=64, width=80,
                             n_targets=1, directions=[30.0], speed=[0.5, 0.5])
    (tmp_path / "rec" / "frames").mkdir(parents=True)
    for i, frame in enumerate(frames):
        cv2.imwrite(str(tmp_path / "rec" / "frames" / f"{i + 1:04d}.png"), frame)
    (tmp_path / "rec" / "truth.txt").write_text(
        "".join(f"{x:.2f} {y:.2f}\n" for x, y in zip(truth["x"], truth["y"])))
    code, _, err = cli("process", "rec")
    assert code == 0, err
    assert (tmp_path / "rec.irdetect.h5").exists()
    code, out, err = cli("evaluate", "rec.irdetect.h5", "--json")
    assert code == 0, err
    import json
    assert json.loads(out)["detection"]["targets"] == 3


def test_convert_says_a_missing_input_before_an_existing_output(cli, tmp_path):
    (tmp_path / "out.h5").write_bytes(b"")
    code, _, err = cli("convert", "missing.h5", "-o", "out.h5")
    assert code == 2 and "missing.h5" in err and "file not found" in err


def test_evaluate_prints_a_legend_line_under_its_table(cli):
    code, _, err = cli("simulate", "seq.h5", "--seed", "1", "--frames", "36", "--size", "64x64",
                       "-q")
    assert code == 0, err
    code, _, err = cli("process", "seq.h5", "-o", "res.h5", "-q")
    assert code == 0, err
    code, out, err = cli("evaluate", "res.h5")
    assert code == 0, err
    last = out.strip().splitlines()[-1]
    assert last.startswith("legend: ")
    for words in ("pd = ", "pixel_fa = ", "pt = ", "pc = ", "gate = match distance (px)"):
        assert words in last


def test_every_help_reads_as_user_text(capsys):
    from irdetect.cli import COMMANDS, main

    for name, _, _ in COMMANDS:
        with pytest.raises(SystemExit):
            main([name, "--help"])
        text = capsys.readouterr().out
        assert "`" not in text and "SECTIONS" not in text, name
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    assert "irdetect track" in capsys.readouterr().out     # not only process results
