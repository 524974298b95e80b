"""`tapcell analyze` reads its common command line (`[--json] FILE...`) without argparse: whatever it
is given, the options are argparse's, and so are the error and its exit status."""

from __future__ import annotations

import contextlib
import io

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tapcell.tap import cli

# Options, their values, abbreviations, files, and names argparse might take for options.
TOKENS = ["--json", "--pool", "--plot", "out.png", "--set", "mains_hz=auto", "--js", "--jsonx", "-h",
          "--", "-", "", "a.json", "b.jsonl", "c d.csv", "-1", "x=y", "--json=1", "@list"]


def _answer(read, argv):
    """The options `read` finds in argv, or its exit status; with what it printed (usage, error)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            answer = ("options", vars(read(argv)))
        except SystemExit as stop:
            answer = ("exit", stop.code)
    return answer, out.getvalue(), err.getvalue()


def _argparse_answer(argv):
    return _answer(lambda args: cli._parser().parse_args(args), argv)


def _our_answer(argv):
    return _answer(cli._arguments, argv)


@pytest.mark.parametrize("argv", [
    ["a.json"], ["--json", "a.json"], ["--json", "a.json", "b.jsonl", "c d.csv"], ["--json", "--json", "a.json"],
    [""], ["a.json", "--json"], ["a.json", "--json", "b.json"], ["--json"], [], ["--pool", "a.json"],
    ["--json", "-", "a.json"], ["--json", "--", "a.json"], ["a.json", "-1"], ["--js", "a.json"], ["-h"],
])
def test_the_options_are_argparse_s(argv):
    assert _our_answer(argv) == _argparse_answer(argv)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(TOKENS), max_size=6))
def test_any_command_line_reads_as_argparse_reads_it(argv):
    assert _our_answer(argv) == _argparse_answer(argv)


def test_the_common_call_builds_no_parser(monkeypatch):
    def no_parser():
        raise AssertionError("argparse was asked")

    monkeypatch.setattr(cli, "_parser", no_parser)
    options = cli._arguments(["--json", "a.json", "b.json"])
    assert vars(options) == {"files": ["a.json", "b.json"], "json": True, "plot": None, "pool": False, "set": []}
    assert vars(cli._arguments(["a.json"]))["json"] is False
