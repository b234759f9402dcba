"""Simulators with ground truth: IR image sequences (and, beside them, radar-style scans)."""

from irdetect.simulate.sequence import (SequenceScenario, load_scenario, simulate,
                                        simulate_blocks)

__all__ = ["SequenceScenario", "load_scenario", "simulate", "simulate_blocks"]
