"""Config is data: each stage's dataclass mirrors its function's keyword parameters."""

import dataclasses
import inspect
import json

import pytest

from irdetect import config
from irdetect.errors import InputError


def _stage_functions():
    from irdetect import combine, correlate, detect, fuse, initiate, suppress

    return [(config.SuppressConfig, suppress.suppress), (config.CombineConfig, combine.combine),
            (config.DetectConfig, detect.detect), (config.FuseConfig, fuse.fuse),
            (config.CorrelateConfig, correlate.correlate),
            (config.InitiateConfig, initiate.initiate_detections)]


@pytest.mark.parametrize("cls, function", _stage_functions(),
                         ids=lambda v: getattr(v, "__name__", ""))
def test_stage_config_mirrors_keyword_parameters(cls, function):
    keywords = {name: p.default for name, p in inspect.signature(function).parameters.items()
                if p.kind is inspect.Parameter.KEYWORD_ONLY}
    fields = {f.name: f.default for f in dataclasses.fields(cls)}
    fields.pop("long_memory", None)      # the pipeline's: which frames it passes as long_past
    fields.pop("gain_step", None)        # the reader's: it undoes the gain control
    fields.pop("bin", None)              # the driver's: it bins the frames it reads
    assert fields == keywords


def test_toml_round_trip_and_errors(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[combine]\nlength = 6\nstep = 6\n[detect]\nk = 5\n")
    cfg = config.load_config(path)
    assert cfg.combine.length == 6 and cfg.detect.k == 5.0
    assert json.loads(config.to_json(cfg))["combine"]["length"] == 6
    path.write_text("[combine]\nlength = 'twelve'\n")
    with pytest.raises(InputError, match="combine.length must be int"):
        config.load_config(path)
    path.write_text("[colour]\nx = 1\n")
    with pytest.raises(InputError, match="unknown config key config.colour"):
        config.load_config(path)
    path.write_text("[combine\n")
    with pytest.raises(InputError, match="not a valid TOML"):
        config.load_config(path)
