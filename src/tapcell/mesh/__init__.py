"""Mesh and levelling math: geometry, interpolation, fade, move splitting, profiles,
the two-pass ABL, thermal adjustment, Prusa-matched thresholds and reports.

Everything here is plain functions and dataclasses over numpy arrays; the G-code commands
and the probing that feed it live above (see docs/mesh.md).
"""
