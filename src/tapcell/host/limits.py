"""The ranges every machine number is checked against (toolhead, G-code frame, heaters).

No printer is 10 m wide, and speeds, accelerations and temperatures have ceilings far above
any real machine. The floor of the speeds keeps a move from lasting days (the virtual printer
simulates every second).
"""

MAX_COORDINATE_MM = 10_000.0
SPEED_MM_S = (0.1, 10_000.0)
# As getter keywords: getfloat("position_min", 0.0, **COORDINATE_RANGE).
COORDINATE_RANGE = {"minval": -MAX_COORDINATE_MM, "maxval": MAX_COORDINATE_MM}
SPEED_RANGE = {"minval": SPEED_MM_S[0], "maxval": SPEED_MM_S[1]}
# F in mm/min.
FEED_RANGE = {"minval": SPEED_MM_S[0] * 60.0, "maxval": SPEED_MM_S[1] * 60.0}
ACCEL_MM_S2 = (1.0, 1_000_000.0)
ACCEL_RANGE = {"minval": ACCEL_MM_S2[0], "maxval": ACCEL_MM_S2[1]}
MICROSTEPS = (1, 2, 4, 8, 16, 32, 64, 128, 256)
MAX_ROTATION_DISTANCE_MM = 1000.0
MAX_FULL_STEPS_PER_ROTATION = 10_000
MAX_TEMP_C = 1000.0
ABSOLUTE_ZERO_C = -273.15
TEMPERATURE_RANGE = {"minval": ABSOLUTE_ZERO_C, "maxval": MAX_TEMP_C}
# A share (0..1): fan speeds, powers, pin values.
SHARE_RANGE = {"minval": 0.0, "maxval": 1.0}
# Time constants and periods of the hardware options kept as written (cycle times, smoothing).
SECONDS_RANGE = {"above": 0.0, "maxval": 3600.0}
