"""One module or package per config section (`[load_cell]` -> `tapcell.extras.load_cell`)."""
