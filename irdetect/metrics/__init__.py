"""Scoring against ground truth: detections (Pd, false alarms), initiated tracks (Pt, Pc, OSPA), frame-by-frame tracks (CLEAR-MOT, IDF1)."""
