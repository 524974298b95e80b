"""The mcu link: the firmware core (firmware/) called through cffi.

Each submodule declares the C API it uses and loads the shared host build of the
firmware through `_lib.load(cdef)`: `trigger` (filter + load-cell trigger),
`sensors` (HX71x / ADS1220 drivers).
"""
