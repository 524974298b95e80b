"""An independent tap generator and a benchmark that scores tap analyzers on its taps.

`taplab` shares no code with the virtual printer (`tapcell.sim`) or with the analysis' own
synthetic taps (`tapcell.tap.synth`): the analysis is scored on physics it was not written
against. numpy only. See docs/tap-analysis.md ("Independent benchmark").
"""
