"""Frame-by-frame multi-target tracking of small IR targets (Cheng et al.).

Stages: :mod:`~irdetect.track.regions` (candidate regions and their features),
:mod:`~irdetect.track.seasky` (sea-sky line), :mod:`~irdetect.track.fcm` (fuzzy c-means),
:mod:`~irdetect.track.tracker` (FCM + adaptive PMHT tracker, CV Kalman + GNN baseline), and
:func:`track`, which runs them over a sequence.
"""

from irdetect.track.fcm import fcm, fcm_memberships
from irdetect.track.pipeline import track
from irdetect.track.regions import REGION, extract_regions
from irdetect.track.seasky import find_sea_sky_line, sea_sky_band
from irdetect.track.tracker import FCMPMHTTracker, GNNTracker

__all__ = ["track", "extract_regions", "REGION", "find_sea_sky_line", "sea_sky_band",
           "fcm", "fcm_memberships", "FCMPMHTTracker", "GNNTracker"]
