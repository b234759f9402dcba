"""A wheel (``pip install .``, not editable) must carry the files of data/ the code reads."""

import sys
import tomllib
from pathlib import Path

import irdetect
from irdetect.simulate.presets import PRESETS

ROOT = Path(__file__).resolve().parents[1]


def test_every_data_folder_is_installed_by_a_wheel():
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())
    data_files = conf["tool"]["setuptools"]["data-files"]
    shipped = {f for patterns in data_files.values() for pattern in patterns
               for f in ROOT.glob(pattern)}
    on_disk = {f for f in (ROOT / "data").rglob("*") if f.is_file()}
    assert on_disk and on_disk <= shipped, sorted(map(str, on_disk - shipped))
    for target, patterns in data_files.items():
        for pattern in patterns:    # share/irdetect/<name> holds data/<name>/...
            assert target == "share/irdetect/" + Path(pattern).parent.relative_to("data").as_posix()


def test_data_dir_finds_the_checkout_first_and_the_installed_copy_otherwise(monkeypatch, tmp_path):
    assert PRESETS == ROOT / "data" / "presets"
    monkeypatch.setattr(irdetect, "__file__", str(tmp_path / "irdetect" / "__init__.py"))
    monkeypatch.setattr(sys, "prefix", str(tmp_path / "env"))
    assert irdetect.data_dir("presets") == tmp_path / "env" / "share" / "irdetect" / "presets"
