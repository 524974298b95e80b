"""Tap analysis: tap files, decomposition, Z at break contact, validation, quality classifiers.

Public API (see docs/tap-analysis.md):
    read_tap_file(path) -> list[TapData]
    analyze_tap(tap, options=None) -> TapAnalysis
    tap_to_json_dict(tap, analysis=None) -> dict     (a tapcell.tap.v1 object)
    get_classifier(name, options=None) -> classifier
"""

from tapcell.tap.analysis import analyze_tap
from tapcell.tap.classifiers import Classification, TapRejected, UnknownClassifierError, get_classifier
from tapcell.tap.model import AnalysisOptions, Move, TapAnalysis, TapData, TapFileError
from tapcell.tap.readers import read_tap_file, tap_to_json_dict

__all__ = [
    "AnalysisOptions",
    "Classification",
    "Move",
    "TapAnalysis",
    "TapData",
    "TapFileError",
    "TapRejected",
    "UnknownClassifierError",
    "analyze_tap",
    "get_classifier",
    "read_tap_file",
    "tap_to_json_dict",
]
