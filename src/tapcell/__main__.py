from tapcell.tools.cli import run

run()
