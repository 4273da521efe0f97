"""The names of the test kinds, without their schemas.

:mod:`schemas.kinds` builds Arrow schemas when imported; code that only needs the names (the
rebuild's clean-up, which must recognise its own ``samples/kind=<name>/`` folders) reads them
here. :mod:`schemas.kinds` checks that its ``KINDS`` are exactly these.
"""

KIND_NAMES = ("leakage", "breakaway", "viscous", "identification", "step", "spring", "pressure_step", "durability",
              "timeseries")
