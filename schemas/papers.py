"""The two papers the lab's benches reproduce, cited once for the whole code (docs/physics.md).

The report's headings, the figures' captions and the findings' ``paper`` column all take their
citation from here.
"""
#: The PLPA paper: a pneumatic linear peristaltic actuator.
PLPA_CITATION = "Carneiro et al. 2020, Information 11(2):76"
#: The PLA paper: a conventional double-acting pneumatic cylinder.
PLA_CITATION = "Palomares et al. 2017, Mechatronics 45"


# -- findings and analyses -----------------------------------------------------------------------------
#: PLPA paper, section 3.1 (Figs. 9-10): the rollers' spring force at 100 % (settings 33 %, 66 %,
#: 100 % of it). [N]
PLPA_SPRING_FORCE_MAX_N = 1300.0
#: PLPA paper, section 3.2.1 (Fig. 12): the breakaway force at 0 bar backpressure is "about twice"
#: that at >= 1 bar, read as a ratio of the means within this band. [-]
PLPA_BREAKAWAY_RATIO_BAND = (1.5, 2.5)
#: PLA paper, Table 3: the fitted models reproduce every test with NRMSE below this (1.16-2.39 %):
#: the findings' criterion and the limit the analyses hold a model fit to. [%]
PLA_NRMSE_LIMIT_PCT = 2.5
