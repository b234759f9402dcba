"""Write a synthetic IR sequence with ground truth (/frames, /truth) to an HDF5 file.

Presets live in data/presets/*.toml: point-target scenes (wan2008, clutter, demo) and the
harbour scene of extended ships (harbour); any preset field can be overridden. Radar-style
scans have their own command, simulate-scans. The model (SNR = peak amplitude / noise sigma, Gaussian PSF, clutter) is in
docs/simulator.md.
"""

from __future__ import annotations

import logging

import numpy as np
from tqdm import tqdm

from irdetect.errors import InputError, name_options
from irdetect.io import write_sequence
from irdetect.simulate import load_scenario, simulate_blocks
from irdetect.simulate.harbour import harbour_blocks, load_harbour
from irdetect.simulate.presets import preset_kind

log = logging.getLogger(__name__)

#: scenario key -> the option that sets it
OPTIONS = {"snr": "--snr", "n_frames": "--frames", "width": "--size", "height": "--size",
           "n_targets": "--targets", "speed": "--speed", "noise_sigma": "--noise-sigma",
           "psf_sigma": "--psf-sigma", "camera_pan": "--camera-pan",
           "camera_jitter": "--camera-jitter", "agc_step": "--agc", "agc_period": "--agc",
           "dtype": "--dtype"}


def given_options(args, options: dict[str, str]) -> dict[str, str]:
    """Key -> the option as given on the command line (``"--size 0x0"``), for the keys
    of ``options`` whose option was given (``args`` holds it under the key's name, or
    ``size`` for width and height, ``agc`` for its step and period)."""
    out = {}
    for key, option in options.items():
        value = getattr(args, {"--size": "size", "--agc": "agc"}.get(option, key), None)
        if value is not None:
            text = " ".join(f"{v:g}" if isinstance(v, float) else str(v)
                            for v in (value if isinstance(value, (list, tuple)) else [value]))
            out[key] = f"{option} {text}"
    return out


def check_seed(seed: int | None) -> int | None:
    """``--seed``: None (fresh entropy) or an integer >= 0."""
    if seed is not None and seed < 0:
        raise InputError(f"--seed must be an integer >= 0, got {seed}")
    return seed


def add_arguments(p):
    p.add_argument("output", help="HDF5 file to write")
    p.add_argument("--scenario", default="wan2008",
                   help="preset name in data/presets or a TOML file (default: wan2008)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: fresh entropy)")
    p.add_argument("--snr", type=float, help="peak SNR = amplitude / noise sigma")
    p.add_argument("--frames", type=int, dest="n_frames", help="number of frames")
    p.add_argument("--size", metavar="WxH", help="frame size, e.g. 320x240")
    p.add_argument("--targets", type=int, dest="n_targets", help="number of targets")
    p.add_argument("--speed", type=float, nargs=2, metavar=("MIN", "MAX"),
                   help="target speed range in px/frame")
    p.add_argument("--noise-sigma", type=float, help="noise standard deviation (grey levels)")
    p.add_argument("--psf-sigma", type=float, help="target PSF sigma in px (0.6: a 3x3 px "
                   "target; 2: about 9x9)")
    p.add_argument("--camera-pan", type=float, nargs=2, metavar=("VX", "VY"),
                   help="the camera pans: the scene moves VX, VY px/frame in the image")
    p.add_argument("--camera-jitter", type=float, metavar="PX",
                   help="the camera shakes: a random offset of up to PX px per frame and axis")
    p.add_argument("--agc", type=float, nargs=2, metavar=("STEP", "PERIOD"),
                   help="the camera's gain control: the gain switches between 1 and 1 + STEP "
                   "every PERIOD frames (e.g. 0.15 20)")
    p.add_argument("--dtype", choices=["uint8", "uint16", "float32"])
    p.add_argument("--force", action="store_true", help="overwrite an existing output")


def run(args) -> int:
    overrides = {k: getattr(args, k) for k in
                 ("snr", "n_frames", "n_targets", "noise_sigma", "dtype", "psf_sigma",
                  "camera_jitter")}
    if args.speed:
        overrides["speed"] = list(args.speed)
    if args.camera_pan:
        overrides["camera_pan"] = list(args.camera_pan)
    if args.agc:
        step, period = args.agc
        if not period.is_integer():
            raise InputError(f"--agc {step:g} {period:g}: the period must be a whole number "
                             "of frames")
        overrides.update(agc_step=step, agc_period=int(period))
    if args.size:
        w, _, h = args.size.lower().partition("x")
        if not (w.isdigit() and h.isdigit()):
            raise InputError(f"--size must look like 320x240, got {args.size!r}")
        overrides.update(width=int(w), height=int(h))
    rng = np.random.default_rng(check_seed(args.seed))
    kind = preset_kind(args.scenario)
    if kind == "scans":
        raise InputError("a radar scans scenario: use irdetect simulate-scans", args.scenario)
    given = given_options(args, OPTIONS)
    try:
        if kind == "harbour":
            wrong = [given[k] for k in ("snr", "n_targets", "dtype", "psf_sigma", "speed",
                                        "camera_jitter", "camera_pan", "agc_step")
                     if k in given]
            if wrong:
                raise InputError(f"{', '.join(wrong)} {'does' if len(wrong) == 1 else 'do'} "
                                 f"not apply to the harbour scene ({args.scenario})")
            scenario = load_harbour(args.scenario, **overrides)
            blocks, truth = harbour_blocks(scenario, rng)
        else:
            scenario = load_scenario(args.scenario, **overrides)
            blocks, truth = simulate_blocks(scenario, rng)
    except InputError as exc:
        raise name_options(exc, given) from None
    bar = tqdm(total=scenario.n_frames, unit="frame", disable=not args.progress,
               desc="simulate")

    def counted():
        for block in blocks:
            bar.update(len(block))
            yield block

    attrs = {"frame_rate": scenario.frame_rate, "scenario": str(args.scenario),
             "seed": -1 if args.seed is None else args.seed,
             "noise_sigma": scenario.noise_sigma}
    attrs.update({k: getattr(scenario, k) for k in ("snr", "psf_sigma") if hasattr(scenario, k)})
    write_sequence(args.output, counted(), truth=truth, attrs=attrs, force=args.force)
    bar.close()
    log.info("wrote %s: %d frames of %dx%d, %d targets", args.output, scenario.n_frames,
             scenario.width, scenario.height, len(set(truth["target"].tolist())))
    return 0
