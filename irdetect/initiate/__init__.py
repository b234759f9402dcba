"""Track initiation from point measurements gathered over several scans (or combined frames).

Methods (``method=``):

``hough-sc``
    Zhang, Su & Ma (2010): Hough accumulator, every cell with at least T votes is a
    candidate, subtractive clustering of the candidates' (rho, theta), one track per centre.
``hough``
    Plain threshold baseline: every cell with at least T votes is a track.
``nms``
    Greedy non-maximum suppression of the accumulator (cell units) instead of clustering.
``opencv``
    ``cv2.HoughLinesPointSet`` (OpenCV's own voting and local-maximum test).
``parallel-hough``
    Lu et al. (2013): one binary accumulator per scan; a cell counts only when every scan
    votes for it; cells at ``parallel_fraction`` x peak or more are tracks.
``fuzzy-parallel-hough``
    Liang, Wang & Guo (2015): Gaussian memberships (eq. 6-8) per scan, rule q1 on every
    scan, cells at ``q2`` x peak or more are tracks; ``merge_peaks=True`` merges the cells
    of a peak by subtractive clustering.
``mn-logic``
    Sequential M-of-N logic (MATLAB ``trackHistoryLogic``) with a velocity gate.

Every Hough method recovers the measurements supporting each selected cell; with
``verify=True`` (the default, beyond the papers) they are kept only when they form a
constant-velocity track: one measurement per scan, speed within [v_min, v_max], every
position within ``gate`` sigma of a least-squares constant-velocity fit (in range /
cross-range terms for polar measurements), a fit chi-square within the ``fit_confidence``
quantile (2n - 4 degrees of freedom), at least ``min_hits`` of the window's scans. All
cells are handled as arrays (no loop over cells or hypotheses). Coordinates: x = column,
y = row (pixels) for images, the file's units for scans; time in frames or seconds.

Layout (one module per role, one contract): ``hough_sc`` (hough-sc, hough, nms, opencv),
``parallel`` (parallel-hough, fuzzy-parallel-hough), ``mn_logic`` (mn-logic), each with
``initiate(points, *, params) -> (rows, members)`` (``contract``: ``initiate``, the
dispatch); ``common`` the constant-velocity check and the merging of windows; ``base`` the
parameters, the window of measurements, support recovery and result rows; ``images``
``initiate_detections`` and the tracks' positions; ``scans`` ``initiate_scans``;
``sensor`` the sensor model and the parameters derived from it (``derive_params``);
``clutter`` the per-track clutter test (``false_tracks``: could clutter of the measured
density have made a chain as good, anywhere in the window?).
"""

from irdetect.initiate.base import DEFAULTS, METHODS, POINT, ROW, check_params
from irdetect.initiate.common import (_fit_chi2, fit_constant_velocity, merge_windows,
                                      scan_windows)
from irdetect.initiate.contract import METHOD_MODULES, initiate, initiate_points
from irdetect.initiate.images import (camera_at, initiate_detections, positions_at,
                                     track_positions)
from irdetect.initiate.scans import initiate_scans
from irdetect.initiate.sensor import SensorModel, derive_params

# the names of the single module this package replaced (irdetect/initiate.py)
_ROW = ROW
_check_params = check_params

__all__ = ["DEFAULTS", "METHODS", "METHOD_MODULES", "POINT", "ROW", "SensorModel",
           "camera_at", "check_params", "derive_params", "fit_constant_velocity", "initiate",
           "initiate_detections", "initiate_points", "initiate_scans", "merge_windows",
           "positions_at", "scan_windows", "track_positions"]
