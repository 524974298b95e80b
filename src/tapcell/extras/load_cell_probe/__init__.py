"""`[load_cell_probe]`: the load-cell probe (device, options)."""
