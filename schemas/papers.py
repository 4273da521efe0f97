"""The two papers the lab's benches reproduce, cited once for the whole code (docs/physics.md).

The report's headings, the figures' captions and the findings' ``paper`` column all take their
citation from here.
"""
#: The PLPA paper: a pneumatic linear peristaltic actuator.
PLPA_CITATION = "Carneiro et al. 2020, Information 11(2):76"
#: The PLA paper: a conventional double-acting pneumatic cylinder.
PLA_CITATION = "Palomares et al. 2017, Mechatronics 45"
